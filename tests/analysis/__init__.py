"""Tests of sgfd_analysis: the paper's figures and the correlation analysis."""
