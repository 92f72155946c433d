"""The command line's error for bad input."""


class UsageError(Exception):
    """Bad input from the command line: printed as one line, exit status 2."""
