"""The ``unshadowed`` method's Python side: diffuse environment lighting
without visibility, from the irradiance map. It needs nothing but its renderer
parameters, so the plain Technique serves; the README's benchmark table shows
it at its defaults."""

from __future__ import annotations

from .base import Technique


class Unshadowed(Technique):
    readme_setting: dict = {}


TECHNIQUE = Unshadowed("unshadowed")
