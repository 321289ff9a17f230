"""The one error type of both command lines."""


class UsageError(Exception):
    """Bad input the user can fix: printed as one line, exit status 2."""
