"""``qifreport --profile`` and the batch workers' peak memory belong to their own process."""

import subprocess
import sys

import numpy as np
import pytest

from qifreport.profile import peak_rss_bytes, rss_bytes


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux /proc accounting")
def test_child_peak_is_not_the_parents():
    """Linux carries ``ru_maxrss`` across exec: a child of a large process would report the
    parent's size as its own peak. ``peak_rss_bytes`` reads the child's own high-water mark."""
    big = np.ones(400 * 2**20 // 8)  # 400 MiB resident in this (parent) process
    big[::512] += 1.0
    assert rss_bytes() > 400 * 2**20
    code = (
        "import resource; from qifreport.profile import peak_rss_bytes; "
        "print(peak_rss_bytes(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    own, maxrss = int(out[0]), int(out[1])
    # an interpreter with numpy: tens of MiB (ru_maxrss says >= 400 MiB on Linux here)
    assert own < 200 * 2**20, (own, maxrss)
    assert peak_rss_bytes() >= rss_bytes() > 400 * 2**20  # and the parent sees its own
    del big
