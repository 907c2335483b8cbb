"""``qifreport --profile``: wall time and peak resident memory per stage.

A sampler thread reads the process's resident set size (``/proc/self/statm``; elsewhere the
running peak of ``getrusage``) every ``interval`` seconds; a stage's peak is the largest
sample inside its time window, and the whole run's peak is the kernel's high-water mark
(exact, whatever the sampling missed): ``VmHWM`` of ``/proc/self/status``, which belongs to
this program's address space. (``ru_maxrss`` is not used where ``/proc`` exists: Linux
carries it across ``exec``, so a process started by a large parent reports the parent's
resident size at ``fork`` as its own peak.)
"""

from __future__ import annotations

import os
import resource
import threading
import time
from dataclasses import dataclass, field

__all__ = [
    "Profiler",
    "peak_rss_bytes",
    "rss_bytes",
]

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def rss_bytes() -> int:
    """Current resident set size of this process, bytes."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * _PAGE
    except OSError:
        return peak_rss_bytes()


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far, bytes (``VmHWM``; elsewhere
    ``ru_maxrss``)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024  # kB
    except (OSError, ValueError, IndexError):
        pass
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024


@dataclass
class Profiler:
    """Stage windows and a background RSS sampler.

    Use :meth:`stage` as a context manager around CLI-level stages, and :meth:`add_stages`
    for the library's own sequential timings (``InspectionResult.timings``) measured from a
    known start time.
    """

    interval: float = 0.05
    stages: list[tuple[str, float, float]] = field(default_factory=list)
    samples: list[tuple[float, int]] = field(default_factory=list)
    #: peak RSS (bytes) of each child process the run forked (their shared pages included)
    children: list[int] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None

    def start(self) -> Profiler:
        def run() -> None:
            while not self._stop.is_set():
                self.samples.append((time.perf_counter(), rss_bytes()))
                self._stop.wait(self.interval)

        self._thread = threading.Thread(target=run, name="rss-sampler", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        self.samples.append((time.perf_counter(), rss_bytes()))

    def stage(self, name: str):
        prof = self

        class _Stage:
            def __enter__(self):
                self.t0 = time.perf_counter()
                return self

            def __exit__(self, *exc):
                prof.stages.append((name, self.t0, time.perf_counter()))
                return False

        return _Stage()

    def add_stages(self, start: float, timings: dict[str, float], prefix: str = "") -> None:
        """Windows of sequential stages ``timings`` (name -> seconds) run from ``start``."""
        t = start
        for name, secs in timings.items():
            self.stages.append((prefix + name, t, t + secs))
            t += secs

    def peak_in(self, t0: float, t1: float) -> int:
        """Largest sample in ``[t0, t1]``; a stage shorter than the sampling interval gets
        the samples either side of it."""
        inside = [r for t, r in self.samples if t0 <= t <= t1]
        if inside:
            return max(inside)
        before = [r for t, r in self.samples if t < t0][-1:]
        after = [r for t, r in self.samples if t > t1][:1]
        return max(before + after, default=0)

    def table(self) -> str:
        """One line per stage (seconds, peak RSS in the window), then the run's peak."""
        lines = [f"{'stage':28s} {'seconds':>9s} {'peak RSS, MiB':>14s}"]
        for name, t0, t1 in self.stages:
            lines.append(f"{name:28s} {t1 - t0:9.2f} {self.peak_in(t0, t1) / 2**20:14.0f}")
        if self.stages:
            total = max(t1 for _, _, t1 in self.stages) - min(t0 for _, t0, _ in self.stages)
            lines.append(f"{'total':28s} {total:9.2f} {peak_rss_bytes() / 2**20:14.0f}")
        if self.children:
            lines.append(
                f"{len(self.children)} forked children, the largest's peak RSS "
                f"{max(self.children) / 2**20:.0f} MiB (pages shared with this process included)"
            )
        return "\n".join(lines)
