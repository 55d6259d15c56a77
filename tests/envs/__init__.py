"""Tests of sgfd_envs: the ids, their domains, and each benchmark's pixels."""
