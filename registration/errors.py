"""Errors raised on bad input (the class lives upstream, in :mod:`step.errors`)."""

from step.errors import InputError

__all__ = ["InputError"]
