"""Errors raised on bad input; the CLI turns them into a one-line message and exit code 2.

Defined here, in the most upstream package, so that every stage (``step`` ->
``registration`` -> ``metrology`` -> ``qif``) raises the same class without importing a
downstream one.
"""

import os
import signal
import sys

__all__ = [
    "InputError",
    "Interrupted",
    "pending_interrupt",
    "raise_if_interrupted",
]


class InputError(ValueError):
    """An input file or array that cannot be inspected (missing, corrupt, empty, NaN, ...)."""


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP during a run: the atomic writers remove their temporary files
    on the way out, and the command ends with one line and exit ``128 + signal``.

    Every one raised is remembered (:func:`raise_if_interrupted`): a library that swallows it
    (an optional import guarded by a bare ``except``) cannot make the run carry on to write
    its outputs.
    """

    #: the signals raised so far in this process (the command line's own state: a signal
    #: is process-wide)
    received: list[int] = []

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum
        self.name = signal.Signals(signum).name
        Interrupted.received.append(signum)

    def leave(self) -> None:
        """End the process now: the command's one line on stderr, exit ``128 + signal``
        (no finalisation: an extension caught mid-computation can crash in it)."""
        print(f"qifreport: interrupted by {self.name}: nothing written", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(128 + self.signum)


def pending_interrupt(exc: BaseException) -> Interrupted | None:
    """The interruption behind ``exc``: ``exc`` itself, or the signal received while an
    extension turned its exception into another one (NumPy's import reports a Ctrl-C
    during its C set-up as an ``ImportError``); None when no signal arrived."""
    if isinstance(exc, Interrupted):
        return exc
    if Interrupted.received:
        return Interrupted(Interrupted.received[0])
    return None


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` again if a signal arrived earlier and was swallowed."""
    if Interrupted.received:
        raise Interrupted(Interrupted.received[0])
