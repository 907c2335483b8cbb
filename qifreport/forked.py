"""Run one call in a forked child process while the caller goes on (Linux).

:class:`ForkExecutor` has the one method of :class:`concurrent.futures.Executor` that
:func:`qifreport.schedule.inspect_beside` uses, ``submit(fn, *args, **kwargs)``. The
inspection gives it the free-state judgement, which needs the CPU while the virtual fixture
runs in the caller: threads cannot share that work (the judgement is many short numpy calls
that hold the GIL; measured on the sample panel: no gain), a forked child can, and it starts
with the caller's arrays without copying or pickling them (copy-on-write). Only the
result travels back, pickled through a pipe.

The child never writes a file and never runs the parent's exit handlers (``os._exit``); it
takes the default action of SIGINT/SIGTERM, so an interrupted command stops it too, and
:meth:`ForkedCall.cancel` kills it when the caller no longer needs it. Whatever goes wrong
in the child (an exception, a crash, a result that does not pickle, no answer within the
time limit) the call is made again in the caller, so the outcome is the sequential one and
only the time differs.
"""

from __future__ import annotations

import logging
import os
import pickle
import select
import signal
import sys
import time
from collections.abc import Callable
from typing import Any

from .profile import peak_rss_bytes

__all__ = ["ForkExecutor", "ForkedCall", "fork_executor", "in_fork"]

log = logging.getLogger(__name__)


def _cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


#: a child is given up (and the call made in the caller) when it has not answered within
#: this many times the time the caller took until it asked (and at least the timeout)
SLOWER = 5.0


#: non-empty while the main thread is inside ``os.fork``: its at-fork handlers (logging's
#: lock release) run Python code, and an exception a signal handler raises there is printed
#: and dropped (:func:`in_fork`)
_FORKING: list[bool] = []


def in_fork() -> bool:
    """Whether the main thread is inside ``os.fork`` (a signal handler that raises should
    wait: :func:`qifreport.cli` defers it as it does for worker threads)."""
    return bool(_FORKING)


def fork_executor() -> ForkExecutor | None:
    """A :class:`ForkExecutor` where forking is safe and a second CPU is free to use: Linux
    (macOS's system libraries are not fork-safe; Windows has no fork) with at least two
    CPUs in this process's affinity; otherwise None (run sequentially)."""
    if not sys.platform.startswith("linux") or not hasattr(os, "fork") or _cpus() < 2:
        return None
    return ForkExecutor()


class ForkedCall:
    """The pending result of one call in a forked child (:meth:`ForkExecutor.submit`)."""

    def __init__(
        self,
        fn: Callable[..., Any],
        args: tuple,
        kwargs: dict,
        timeout: float,
        peaks: list[int] | None = None,
    ):
        self._fn, self._args, self._kwargs = fn, args, kwargs
        self._peaks = peaks
        self._timeout = timeout
        self._started = time.monotonic()
        self._done = False
        self._value: Any = None
        self._reaped = True  # until there is a child
        try:
            read, write = os.pipe()
        except OSError as e:  # no descriptors left: computed in the caller
            log.info("no pipe for a forked %s (%s): computed here", self._name(), e)
            self._pid = -1
            return
        try:
            _FORKING.append(True)
            try:
                pid = os.fork()
            finally:
                _FORKING.clear()
        except OSError as e:  # no memory or no process slot to fork with
            os.close(read)
            os.close(write)
            log.info("cannot fork for %s (%s): computed here", self._name(), e)
            self._pid = -1
            return
        if pid == 0:  # the child: compute, send, leave without the parent's exit handlers
            os.close(read)
            code = 0
            try:
                signal.signal(signal.SIGINT, signal.SIG_DFL)
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                value = fn(*args, **kwargs)
                data = pickle.dumps((value, peak_rss_bytes()), protocol=pickle.HIGHEST_PROTOCOL)
                with os.fdopen(write, "wb") as f:
                    f.write(data)
            except BaseException:  # noqa: BLE001 - any failure: the parent computes it
                code = 1
            finally:
                os._exit(code)
        os.close(write)
        self._pid, self._fd = pid, read
        self._reaped = False

    def _reap(self, kill: bool) -> int:
        """Close the pipe, kill the child if asked, and wait for it (once); its exit status."""
        if self._reaped:
            return -1
        self._reaped = True
        os.close(self._fd)
        if kill:
            try:
                os.kill(self._pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        _, status = os.waitpid(self._pid, 0)
        return status

    def result(self) -> Any:
        """The call's value: the child's, or (when the child failed) the caller's own."""
        if self._done:
            return self._value
        if self._pid < 0:  # never forked
            return self._local()
        chunks = []
        # the child's work is about the size of the caller's meanwhile: a child that takes
        # many times as long is stuck (a lock a thread of the caller held at the fork)
        waited = max(self._timeout, SLOWER * (time.monotonic() - self._started))
        deadline = self._started + waited
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([self._fd], [], [], left)[0]:
                    raise TimeoutError
                chunk = os.read(self._fd, 1 << 20)
                if not chunk:
                    break
                chunks.append(chunk)
        except TimeoutError:
            self._reap(kill=True)
            log.warning(
                "the forked %s gave no answer in %.0f s: computed here", self._name(), waited
            )
            return self._local()
        except BaseException:  # interrupted while waiting: stop the child too
            self._reap(kill=True)
            raise
        status = self._reap(kill=False)
        if status != 0 or not chunks:
            log.info("the forked %s failed (status %d): computed here", self._name(), status)
            return self._local()
        self._value, peak = pickle.loads(b"".join(chunks))
        if self._peaks is not None:
            self._peaks.append(peak)
        self._done = True
        return self._value

    def done(self) -> bool:
        """Whether the child has answered (or ended): :meth:`result` would not wait for it."""
        if self._done:
            return True
        if self._pid < 0 or self._reaped:
            return False
        return bool(select.select([self._fd], [], [], 0)[0])

    def cancel(self) -> bool:
        """Stop the child if its result was not taken (True when it was stopped)."""
        if self._done:
            return False
        self._reap(kill=True)
        self._done = True
        return True

    def __del__(self) -> None:  # abandoned (an exception unwound its caller): no orphan
        try:
            self.cancel()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

    def _local(self) -> Any:
        self._value = self._fn(*self._args, **self._kwargs)
        self._done = True
        return self._value

    def _name(self) -> str:
        return getattr(self._fn, "__name__", "call")


class ForkExecutor:
    """``submit(fn, *args, **kwargs)`` runs the call in a forked child process
    (:class:`ForkedCall`); ``timeout`` (s) and :data:`SLOWER` times the caller's own time
    until it asks bound how long :meth:`ForkedCall.result`
    waits for it before computing it in the caller.

    Attributes
    ----------
    peaks : the peak resident set size (bytes, ``VmHWM``) of each child that answered: its
        pages shared with the caller (copy-on-write) included.
    """

    def __init__(self, timeout: float = 60.0):
        self.timeout = float(timeout)
        self.peaks: list[int] = []

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> ForkedCall:
        return ForkedCall(fn, args, kwargs, self.timeout, self.peaks)
