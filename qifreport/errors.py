"""Errors raised on bad input; the CLI turns them into a one-line message and exit code 2.

Defined here, in the most upstream package, so that every stage (``step`` ->
``registration`` -> ``metrology`` -> ``qif``) raises the same class without importing a
downstream one.
"""

__all__ = [
    "InputError",
]


class InputError(ValueError):
    """An input file or array that cannot be inspected (missing, corrupt, empty, NaN, ...)."""
