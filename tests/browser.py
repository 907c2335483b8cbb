"""Headless Chromium for the tests of the HTML viewer (``qifreport --html``).

Debian's ``chromium`` (``make system-deps``) opens the page from ``file://`` with no network
and software WebGL: ANGLE on SwiftShader (``--use-angle=swiftshader``; Chromium no longer
falls back to it silently, hence ``--enable-unsafe-swiftshader``; the old
``--use-gl=swiftshader`` leaves Chromium 156 without any WebGL). The background-networking
flags keep it from trying the network, which on a closed network makes every start slow; a
new profile directory per run keeps runs apart. ``--virtual-time-budget`` lets the page load,
run its script and draw before the screenshot or the DOM is taken.

A missing Chromium fails the test under CI (``CI=true``) and skips it elsewhere.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from tests.consumers import fail_or_skip

#: the flags of every run besides the profile directory
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--virtual-time-budget=2000",
)


def chromium_exe() -> str:
    """Path of Debian's ``chromium``; fails under CI and skips elsewhere when missing."""
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        fail_or_skip("chromium not found: install Debian package chromium (`make system-deps`)")
    return exe


def _run(args: list[str]) -> subprocess.CompletedProcess:
    with tempfile.TemporaryDirectory(prefix="chromium-") as profile:
        return subprocess.run(
            [chromium_exe(), *FLAGS, f"--user-data-dir={profile}", *args],
            capture_output=True,
            text=True,
            timeout=120,
        )


def screenshot(page: Path, png: Path, size: tuple[int, int], fragment: str = "") -> np.ndarray:
    """The page drawn in a ``size = (width, height)`` window: (height, width, 3) int RGB."""
    from PIL import Image

    url = Path(page).resolve().as_uri() + fragment
    r = _run([f"--screenshot={png}", f"--window-size={size[0]},{size[1]}", url])
    assert png.is_file(), f"no screenshot of {url}: {r.stderr[-2000:]}"
    return np.asarray(Image.open(png).convert("RGB")).astype(int)


def dump_dom(page: Path, size: tuple[int, int], fragment: str = "") -> str:
    """The page's DOM after its script ran (``size``: the window, pixels)."""
    url = Path(page).resolve().as_uri() + fragment
    r = _run(["--dump-dom", f"--window-size={size[0]},{size[1]}", url])
    assert r.returncode == 0 and "</html>" in r.stdout, r.stderr[-2000:]
    return r.stdout
