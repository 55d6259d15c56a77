"""Measurements of the package side by side with its references; each script prints its own figures."""
