"""The ``reference`` method's Python side (docs/reference.md): the brute-force
ground truth. Too slow for per-frame use; `penumbra bench` sweeps its
direction grid (face_size) and measures every method against it at a fine one."""

from __future__ import annotations

from .base import Technique


class Reference(Technique):
    interactive = False
    readme_setting = {"face_size": 32}
    readme_label = "face 32"

    def sweep(self) -> list[dict]:
        return [{"face_size": f} for f in (4, 8, 16, 32)]


TECHNIQUE = Reference("reference")
