"""A call made now in another process, or later here: one interface for both.

The command's schedule (:mod:`qifreport.schedule`) hands the inspection's costlier
independent steps (the scan's normals and area, the trim edges) to an executor when it has
one (a forked child, :mod:`qifreport.forked`), else makes them when their result is first
asked for, in the library's sequential order. :func:`submit` returns either as a future
(``result()``, ``cancel()``).
"""

from __future__ import annotations

__all__ = ["Later", "submit"]


class Later:
    """A call made here when its result is asked for (the sequential order), with the
    future's interface :func:`submit` returns."""

    def __init__(self, fn, args) -> None:
        self.fn, self.args, self.done, self.value = fn, args, False, None

    def result(self):
        if not self.done:
            self.value, self.done = self.fn(*self.args), True
        return self.value

    def cancel(self) -> bool:
        return False


def submit(executor, fn, *args):
    """``executor.submit(fn, *args)``; without an executor, the call made when its result
    is asked for."""
    return Later(fn, args) if executor is None else executor.submit(fn, *args)
