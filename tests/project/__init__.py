"""Tests of the project as a whole: installs, the wheel, docs, examples, layering, the device check."""
