"""Tests of sb3_sgfd: the agents, their math, buffers and policies."""
