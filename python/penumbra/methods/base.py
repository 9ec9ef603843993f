"""What every technique's Python module fills in (methods/<name>.py, ``TECHNIQUE``).

The defaults describe a method that needs nothing but renderer parameters:
no scene-file table, no assets, applies to every scene, benchmarked once at
its defaults. render.py, cli.py, bench.py and scenefile.py call only these
hooks; none of them names a technique.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from ..errors import InputError


@dataclass(frozen=True)
class SceneTable:
    """A scene-file table a technique owns (docs/scene-format.md).

    ``key``: the TOML key (``[key]``, or ``[[key]]`` when ``array``);
    ``attr``: the SceneDescription attribute holding the parsed value;
    ``parse(value, base_dir, data)``: the checked value (``value`` is None when
    the file has no such table; ``data`` is the whole parsed file);
    ``content``: whether it adds scene content (geometry) that every method and
    the ground truth see, so a reference cache key must cover it."""

    key: str
    attr: str
    array: bool
    parse: Callable[[Any, Path, dict], Any]
    content: bool = False


class Technique:
    """The Python side of one method of the library."""

    #: renders one frame fast enough to be timed frame after frame (the demo
    #: renders each with full timing); the ground truth and the floor do not.
    interactive = True
    #: part of a benchmark's default method list (when it applies to the scene).
    benchmarked = True
    #: each pixel's shading reads only its own G-buffer texel and the scene, so
    #: a long frame can be shaded in row bands (render(band_progress=...)).
    per_pixel = True
    #: the scene-file tables it owns.
    scene_tables: tuple[SceneTable, ...] = ()
    #: the table its bake parameters go to (None: it has none).
    bake_table: str | None = None
    #: the setting the README's benchmark table shows (None: not in the table), and its label there.
    readme_setting: dict | None = None
    readme_label = ""

    def __init__(self, name: str):
        self.name = name

    @property
    def spec(self):
        from . import spec

        return spec(self.name)

    # ---------------------------------------------------------------- parameters

    def split_params(self, params: dict[str, Any], where: str = "") -> tuple[dict, dict]:
        """(renderer parameters, bake parameters) of flat ``params`` by the
        metadata's stages; unknown names raise InputError listing the method's."""
        renderer, bake = {}, {}
        spec = self.spec
        for name, value in params.items():
            p = spec.param(name)
            if p is None and name in self.bake_aliases():
                bake[name] = value
            elif p is None:
                known = ", ".join(q.name for q in spec.params) or "none"
                raise InputError(f"{where or 'method ' + repr(self.name)}: unknown parameter '{name}' of "
                                 f"{self.name} (its parameters: {known})")
            elif p.stage == "bake":
                bake[name] = value
            else:
                renderer[name] = p.check(value, f"{where} {name}".strip())
        return renderer, bake

    def bake_aliases(self) -> tuple[str, ...]:
        """Bake keys besides the metadata's bake parameters (e.g. a shorthand)."""
        return ()

    def check_render_table(self, table: dict[str, Any]) -> dict[str, Any]:
        """The scene file's [render] parameters of this method, checked against
        the metadata: frame and plan parameters only (a bake parameter belongs
        in the technique's own table)."""
        out = {}
        spec = self.spec
        for name, value in table.items():
            p = spec.param(name)
            if (p is not None and p.stage == "bake") or (p is None and name in self.bake_aliases()):
                raise InputError(f"[render] {name} is a bake option of {self.name}, not a renderer parameter: "
                                 f"set it in [{self.bake_table}]")
            if p is None:
                known = ", ".join(q.name for q in spec.params if q.stage != "bake") or "none"
                raise InputError(f"[render] has unknown key {name} for method {self.name} (its parameters: {known})")
            out[name] = p.check(value, f"[render] {name}")
        return out

    # ---------------------------------------------------------------- scenes and assets

    def applies_to(self, desc) -> bool:
        """Whether the method has something of its own to do in scene ``desc``."""
        return True

    def build(self, built) -> None:
        """Adds what the technique's scene tables describe to a scene being built (render.build_scene)."""

    def prepare(self, built, bake: dict[str, Any], bake_progress=None) -> None:
        """Makes the method's assets (bakes, loads, attaches) before it renders
        ``built``; ``bake``: bake parameters overriding the scene's table."""
        if bake:
            raise InputError(f"method {self.name} has no bake parameters (got {', '.join(bake)})")

    def output_shape(self, renderer, scene, output: str, instance: int, index: int = 0) -> tuple[int, ...]:
        """The float32 array shape of ``output`` (pn_renderer_read_output) of ``instance``, item ``index``."""
        raise InputError(f"method {self.name} has no readable outputs")

    def use_cache_folder(self, desc, folder: Path) -> None:
        """Makes the technique's assets of ``desc`` cache under ``folder`` unless
        the scene names a cache of its own (a benchmark keeps its bakes beside its results)."""

    def content_key(self, desc) -> bytes:
        """Bytes that change when this technique's scene content changes (cache keys of results)."""
        return b""

    # ---------------------------------------------------------------- reports

    def sweep(self) -> list[dict[str, Any]]:
        """The quality settings `penumbra bench` sweeps by default, cheapest first."""
        return [{}]

    def after_render(self, built, renderer) -> None:
        """Called once after render() has rendered ``built`` with ``renderer``
        (e.g. to note what the method chose, for summary_lines and bench_extras)."""

    def summary_lines(self, built) -> list[str]:
        """Lines `penumbra render` / `demo` print after rendering with this method."""
        return []

    def bake_report(self, built) -> dict[str, Any]:
        """What Technique.prepare made for ``built`` (bakes: options, sizes, times), JSON-ready, for reports."""
        return {}

    def bench_extras(self, built) -> dict[str, Any]:
        """Extra fields of a benchmark result row (e.g. its assets' memory)."""
        return {}

    def report_lines(self, results: list[dict]) -> list[str]:
        """Extra lines of a benchmark report about this method's rows."""
        return []

    # ---------------------------------------------------------------- command line

    def add_commands(self, sub) -> dict[str, Callable]:
        """Adds the technique's own `penumbra` subcommands; returns their handlers by name."""
        return {}

    def add_bench_arguments(self, parser) -> None:
        """Adds `penumbra bench` options of the technique's own experiments."""

    def run_bench(self, args) -> int | None:
        """Runs the technique's own `penumbra bench` experiment when its options ask
        for one (returns the exit status), else None."""
        return None
