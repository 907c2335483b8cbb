"""The console entry point: the signals are caught before the command's libraries load.

A command that measures imports NumPy, SciPy, trimesh and the product: about a second, and
several on a loaded machine. A SIGTERM or SIGHUP in that time would end the process by the
signal's default action (no message, no exit code of ours), a Ctrl-C with a traceback. Here
they become :class:`qifreport.errors.Interrupted` from the first instruction, and an
interruption while loading ends as any other: one line, exit ``128 + signal``, nothing
written. :func:`qifreport.cli.main` then installs its own handlers.
"""

from __future__ import annotations

import signal

from qifreport.errors import Interrupted, leave_if_interrupted

__all__ = ["main"]


def _interrupt(signum: int, frame) -> None:
    raise Interrupted(signum)


def main() -> None:
    """``qifreport``: :func:`qifreport.cli.main`, with the signals caught while it loads."""
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), _interrupt)
    try:
        from qifreport.cli import main as cli_main
    except BaseException as exc:
        leave_if_interrupted(exc)
        raise
    cli_main()
