"""A study: its settings schema, the loop of corrections, the runner over executors, the run
store and the analysis of records."""
