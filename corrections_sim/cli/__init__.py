"""The command line: parse, pick executors and output folders, call, print."""
