"""Errors raised on bad input; the CLI turns them into a one-line message and exit code 2.

Defined here, in the most upstream package, so that every stage (``step`` ->
``registration`` -> ``metrology`` -> ``qif``) raises the same class without importing a
downstream one.
"""

import os
import signal
import stat
import sys
from pathlib import Path

__all__ = [
    "EXIT_ERROR",
    "EXIT_FAIL",
    "EXIT_NOT_ESTABLISHED",
    "EXIT_PASS",
    "InputError",
    "Interrupted",
    "file_kind",
    "file_problem",
    "leave_if_interrupted",
    "pending_interrupt",
    "raise_if_interrupted",
    "require_file",
]


#: the command's exit codes: the part passes, fails, the input cannot be inspected, the
#: verdict is not established
EXIT_PASS, EXIT_FAIL, EXIT_ERROR, EXIT_NOT_ESTABLISHED = 0, 1, 2, 3


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

    def leave(self, written: bool = False) -> None:
        """End the process now: the command's one line on stderr, exit ``128 + signal``
        (no finalisation: an extension caught mid-computation can crash in it).

        ``written``: the signal came after the outputs were published (they stand)."""
        done = "after the outputs were written" if written else "nothing written"
        print(f"qifreport: interrupted by {self.name}: {done}", file=sys.stderr)
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


def leave_if_interrupted(exc: BaseException) -> None:
    """End the process as interrupted (:meth:`Interrupted.leave`) when ``exc`` is, or hides,
    a signal (:func:`pending_interrupt`); return otherwise, for the caller to handle
    ``exc``."""
    interrupted = pending_interrupt(exc)
    if interrupted is not None:
        interrupted.leave()


def raise_if_interrupted() -> None:
    """Raise :class:`Interrupted` again if a signal arrived earlier and was swallowed."""
    if Interrupted.received:
        raise Interrupted(Interrupted.received[0])


#: the kinds of file that are not regular files, as a message names them
_SPECIAL_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISSOCK, "a socket"),
)


def file_kind(st: os.stat_result) -> str:
    """What a file is, for a message: ``"a regular file"``, ``"a FIFO"``, ``"a directory"``...

    Parameters
    ----------
    st : its status (:func:`os.stat`).
    """
    if stat.S_ISREG(st.st_mode):
        return "a regular file"
    return next((name for test, name in _SPECIAL_KINDS if test(st.st_mode)), "a special file")


def file_problem(path: Path | str, what: str) -> str | None:
    """Why ``path`` cannot be read as the ``what`` input file (one line), or None when it is
    a regular file (a symbolic link to one included).

    A special file (``/dev/zero``, a FIFO, a directory) is named by its kind: reading one
    never ends or reads nothing useful.
    """
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return f"{what} file not found: {path}"
    except OSError as exc:
        return f"{what} file {path} cannot be read: {exc.strerror or exc}"
    if stat.S_ISREG(st.st_mode):
        return None
    return f"{what} {path} is {file_kind(st)}, not a regular file"


def require_file(path: Path | str, what: str) -> Path:
    """``path`` as a :class:`~pathlib.Path` when it is a regular file.

    Raises
    ------
    InputError
        Missing, unreadable or a special file (:func:`file_problem`'s line).
    """
    problem = file_problem(path, what)
    if problem is not None:
        raise InputError(problem)
    return Path(path)
