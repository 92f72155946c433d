"""A user study run from a protocol: its conditions and questionnaires, each participant's way
through it, simulated cohorts and the power analysis, and the analysis of its log."""
