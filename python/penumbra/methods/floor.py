"""The ``floor`` method's Python side (docs/benchmarks.md): the memory-bound
floor, a timing yardstick rather than a shading method. `penumbra bench` times
it separately (every method's time is reported as a multiple of it), so it is
neither interactive nor in a benchmark's default method list."""

from __future__ import annotations

from .base import Technique


class Floor(Technique):
    interactive = False
    benchmarked = False


TECHNIQUE = Floor("floor")
