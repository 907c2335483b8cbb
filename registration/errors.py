"""Errors raised on bad input; the CLI turns them into a one-line message and exit code 2."""


class InputError(ValueError):
    """An input file or array that cannot be inspected (missing, corrupt, empty, NaN, ...)."""
