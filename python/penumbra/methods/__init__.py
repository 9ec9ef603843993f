"""The shading methods: what the library says about them, and what Python adds.

:func:`catalog` reads the library's method metadata (``pn_method_get_info``,
``pn_method_get_param``, ``pn_method_get_output``) into :class:`MethodSpec` /
:class:`ParamSpec` values: names, one-line summaries, the scene inputs each
method reads, every parameter with its type, stage (``frame``, ``plan`` or
``bake``), default, range, unit and doc, and the readable outputs. Nothing
here restates them.

:func:`technique` gives the Python side of a method: the module of this
package named after it (``methods/fiv.py`` for ``fiv``) holds everything
Python knows about that technique (the scene-file table it owns, how its
assets are prepared, whether it applies to a scene, its benchmark sweep, its
command-line summary) in one :class:`~penumbra.methods.base.Technique`
object, ``TECHNIQUE``. A method of the library without such a module gets the
plain :class:`~penumbra.methods.base.Technique` (renderer parameters only).
"""

from __future__ import annotations

import ctypes
import functools
import importlib
import math
from dataclasses import dataclass
from typing import Any, Iterable

from .. import _native
from ..errors import InputError

STAGES = _native.PARAM_STAGES
RENDERER_STAGES = ("frame", "plan")   # the stages set on a renderer (pn_renderer_set_*); "bake" goes to the asset


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a method as the library declares it (pn_param_info)."""

    name: str
    type: str            # "int" | "float"
    stage: str           # "frame" | "plan" | "bake"
    default: int | float
    min: int | float     # inclusive
    max: int | float     # inclusive
    unit: str
    doc: str

    def check(self, value: Any, where: str = "") -> int | float:
        """``value`` as this parameter takes it (an int, or a float; booleans are
        0/1 ints), or InputError naming ``where`` (e.g. "[render] overlap")."""
        label = where or self.name
        if isinstance(value, bool):
            value = int(value)
        if self.type == "int":
            if not isinstance(value, int):
                raise InputError(f"{label} must be an integer in {self.range_text()}, got {value!r}")
        else:
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise InputError(f"{label} must be a finite number in {self.range_text()}, got {value!r}")
        if not self.min <= value <= self.max:
            raise InputError(f"{label} = {value!r} is outside {self.range_text()}")
        return value

    def range_text(self) -> str:
        return f"[{_number_text(self.min)}, {_number_text(self.max)}]"

    def as_dict(self) -> dict:
        return {"name": self.name, "type": self.type, "stage": self.stage, "default": self.default,
                "min": self.min, "max": self.max, "unit": self.unit, "doc": self.doc}


@dataclass(frozen=True)
class OutputSpec:
    """A readable output of a method (pn_output_info, pn_renderer_read_output)."""

    name: str
    doc: str


@dataclass(frozen=True)
class MethodSpec:
    """A method as the library declares it (pn_method_info and its tables)."""

    name: str
    summary: str
    stage: str                    # its kernel file, kernels/<stage>.cl
    doc_page: str
    inputs: frozenset[str]        # keys of _native.INPUTS
    params: tuple[ParamSpec, ...]
    outputs: tuple[OutputSpec, ...]

    def param(self, name: str) -> ParamSpec | None:
        return next((p for p in self.params if p.name == name), None)

    def params_of(self, *stages: str) -> tuple[ParamSpec, ...]:
        return tuple(p for p in self.params if p.stage in stages)

    def defaults(self, *stages: str) -> dict[str, int | float]:
        return {p.name: p.default for p in self.params_of(*(stages or STAGES))}

    def as_dict(self) -> dict:
        return {"name": self.name, "summary": self.summary, "stage": self.stage, "doc_page": self.doc_page,
                "inputs": sorted(self.inputs, key=list(_native.INPUTS).index),
                "parameters": [p.as_dict() for p in self.params],
                "outputs": [{"name": o.name, "doc": o.doc} for o in self.outputs]}


PARAM_TABLE_HEADER = "| name | type | stage | default | range | unit | meaning |"


def markdown_table(params: Iterable[ParamSpec]) -> str:
    """The parameters as the docs' tables have them (docs/api.md "#### <method>
    parameters", docs/scene-format.md; tests/test_method_docs.py checks them)."""
    lines = [PARAM_TABLE_HEADER, "|---|---|---|---|---|---|---|"]
    for p in params:
        lines.append(f"| `{p.name}` | {p.type} | {p.stage} | {_number_text(p.default)} | {p.range_text()} | "
                     f"{p.unit} | {p.doc} |")
    return "\n".join(lines)


def _number_text(v: int | float) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _text(b: bytes | None) -> str:
    return (b or b"").decode("utf-8", "replace")


def _value(v: float, kind: str) -> int | float:
    return int(v) if kind == "int" and math.isfinite(v) else float(v)


def _read_spec(name: str) -> MethodSpec:
    info = _native.MethodInfo()
    _native.call("pn_method_get_info", None, name.encode(), ctypes.byref(info))
    params = []
    for i in range(info.param_count):
        p = _native.ParamInfo()
        _native.call("pn_method_get_param", None, name.encode(), i, ctypes.byref(p))
        kind = _native.PARAM_TYPES[p.type]
        params.append(ParamSpec(_text(p.name), kind, STAGES[p.stage], _value(p.default_value, kind),
                                _value(p.min, kind), _value(p.max, kind), _text(p.unit), _text(p.doc)))
    outputs = []
    for i in range(info.output_count):
        o = _native.OutputInfo()
        _native.call("pn_method_get_output", None, name.encode(), i, ctypes.byref(o))
        outputs.append(OutputSpec(_text(o.name), _text(o.doc)))
    inputs = frozenset(k for k, bit in _native.INPUTS.items() if info.inputs & bit)
    return MethodSpec(_text(info.name), _text(info.summary), _text(info.stage), _text(info.doc_page), inputs,
                      tuple(params), tuple(outputs))


@functools.cache
def catalog() -> dict[str, MethodSpec]:
    """Every method of the library by name, in the library's order."""
    return {name: _read_spec(name) for name in _native.methods()}


def names() -> tuple[str, ...]:
    return tuple(catalog())


def spec(name: str) -> MethodSpec:
    """The metadata of method ``name``; InputError listing the methods for an unknown one."""
    found = catalog().get(name)
    if found is None:
        raise InputError(f"unknown method '{name}' (available: {', '.join(catalog())})")
    return found


@functools.cache
def technique(name: str):
    """The Python side of method ``name`` (its module's ``TECHNIQUE``)."""
    spec(name)
    try:
        module = importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise
        from .base import Technique

        return Technique(name)
    return module.TECHNIQUE


def techniques() -> list:
    """The Technique of every method, in the library's order."""
    return [technique(name) for name in catalog()]


def scene_tables() -> list:
    """The scene-file tables the techniques own (SceneTable), in the library's method order."""
    return [t for tech in techniques() for t in tech.scene_tables]


def interactive() -> tuple[str, ...]:
    """Methods meant for per-frame use (the demo renders each with full timing)."""
    return tuple(t.name for t in techniques() if t.interactive)


def applicable(desc, methods: Iterable[str] | None = None) -> tuple[str, ...]:
    """``methods`` (default: each method's default for a benchmark) without
    those that have nothing of their own to do in the scene ``desc``."""
    chosen = [t.name for t in techniques() if t.benchmarked] if methods is None else list(methods)
    return tuple(m for m in chosen if technique(m).applies_to(desc))


__all__ = ["MethodSpec", "OutputSpec", "PARAM_TABLE_HEADER", "ParamSpec", "RENDERER_STAGES", "markdown_table", "STAGES", "applicable", "catalog",
           "interactive", "names", "scene_tables", "spec", "technique", "techniques"]
