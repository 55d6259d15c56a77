"""Tests of sgfd_zoo: the sgfd-zoo commands, run folders, sweeps, studies and reports."""
