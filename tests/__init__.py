"""The test suite, one folder per package: envs, agents, zoo, analysis, and the project as a whole."""
