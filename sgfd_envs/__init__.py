"""DeepMind Control generalisation benchmark tasks as gymnasium ids."""
