"""The ``reference`` method's Python side (docs/reference.md): the brute-force
ground truth. Too slow for per-frame use; `penumbra bench` sweeps its
direction grid (face_size) and measures every method against it at a fine one.
By default (face_size = sun_supersampling = 0) the library picks the grid from
the env map; the picks are read back after a render and reported."""

from __future__ import annotations

from .base import Technique


def directions(renderer, scene) -> dict:
    """What a reference renderer uses for ``scene`` (its plan runs first):
    face size, sun supersampling (the automatic picks when set to 0) and the
    number of direction records."""
    face, sun, count = renderer.read_output(scene, "directions", 0, shape=(3,))
    return {"face_size": int(face), "sun_supersampling": int(sun), "directions": int(count)}


class Reference(Technique):
    interactive = False
    # Sweep points fix both grid parameters: left at 0, sun_supersampling would
    # be picked from the env map and the points would not be the face sizes they name.
    readme_setting = {"face_size": 32, "sun_supersampling": 1}
    readme_label = "face 32"

    def sweep(self) -> list[dict]:
        return [{"face_size": f, "sun_supersampling": 1} for f in (4, 8, 16, 32)]

    def output_shape(self, renderer, scene, output: str, instance: int, index: int = 0) -> tuple[int, ...]:
        return (3,)

    def after_render(self, built, renderer) -> None:
        picked = directions(renderer, built.scene)
        picked["auto"] = [k for k in ("face_size", "sun_supersampling") if renderer.get(k) == 0]
        built.assets["reference"] = picked

    def summary_lines(self, built) -> list[str]:
        d = built.assets.get("reference")
        if not d:
            return []
        how = f" ({' and '.join(d['auto'])} chosen from the env map)" if d["auto"] else ""
        return [f"reference: face_size {d['face_size']}, sun_supersampling {d['sun_supersampling']}{how}: "
                f"{d['directions']} directions"]

    def bench_extras(self, built) -> dict:
        d = built.assets.get("reference")
        return {"reference_directions": dict(d)} if d else {}


TECHNIQUE = Reference("reference")
