"""The OpenCL kernel sources shipped with the package (the same files that
are embedded in libpenumbra), and the include expansion the library applies,
so Python code and tests compile exactly what the library compiles."""

from __future__ import annotations

import re
from pathlib import Path

_INCLUDE = re.compile(r'^#include "([^"]+)"\s*$')


def kernel_dir() -> Path:
    """kernels/ installed beside the package, or the source tree's when run from a checkout."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "kernels", here.parent.parent / "kernels"):
        if (candidate / "common" / "math.cl").is_file():
            return candidate
    raise FileNotFoundError("penumbra's kernels/ directory was not found beside the package or in the source tree")


def expand(path: str, extra: str = "") -> str:
    """Source of kernels/`path` with `#include "..."` lines inlined once each,
    as capi/src/context.c does; `extra` (e.g. a test kernel) is appended."""
    root = kernel_dir()
    seen: set[str] = set()
    out: list[str] = []

    def visit(rel: str) -> None:
        if rel in seen:
            return
        seen.add(rel)
        for line in (root / rel).read_text().splitlines(keepends=True):
            m = _INCLUDE.match(line)
            if m:
                visit(m.group(1))
            else:
                out.append(line)

    visit(path)
    for line in extra.splitlines(keepends=True):
        m = _INCLUDE.match(line)
        if m:
            visit(m.group(1))
        else:
            out.append(line)
    return "".join(out)
