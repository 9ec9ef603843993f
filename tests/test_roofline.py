"""bench/roofline.py: the peak FLOP/s and bandwidth kernels that docs/performance.md
compares every kernel against must compile, do their work and give rates."""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import roofline  # noqa: E402


def test_roofline_measures_positive_rates(cl_pair):
    result = roofline.measure(cl_pair[0], mib=4, reps=1)
    for key in ("peak_gflops_fma", "copy_gbs", "read_gbs"):
        assert math.isfinite(result[key]) and result[key] > 0, key
    assert result["compute_units"] >= 1 and result["device"]
