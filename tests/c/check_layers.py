#!/usr/bin/env python3
"""Checks the call structure of libpenumbra's sources from their object files
(`nm`): no two source files call each other in a circle, and internal code
never calls the exported boundary (capi/src/api.c). Run by ctest with the
library's object files as arguments."""

import subprocess
import sys
from pathlib import Path


def symbols(obj: str) -> tuple[set[str], set[str]]:
    out = subprocess.run(["nm", "-P", obj], check=True, capture_output=True, text=True).stdout
    defined, undefined = set(), set()
    for line in out.splitlines():
        parts = line.split()
        if len(parts) < 2:
            continue
        name, kind = parts[0], parts[1]
        if not name.startswith("pn_"):
            continue
        (undefined if kind == "U" else defined).add(name) if kind in "UTDBRtdbr" else None
    return {n for n in defined}, undefined


def source_name(obj: str) -> str:
    # .../CMakeFiles/penumbra.dir/capi/src/core/context.c.o -> capi/src/core/context.c
    p = Path(obj).as_posix()
    key = "/capi/src/"
    return "capi/src/" + p.split(key, 1)[1][: -len(".o")] if key in p else Path(obj).name


def main(objects: list[str]) -> int:
    defs, uses = {}, {}
    for obj in objects:
        name = source_name(obj)
        defs[name], uses[name] = symbols(obj)
    owner = {sym: f for f, ds in defs.items() for sym in ds}
    edges = {f: sorted({owner[s] for s in uses[f] if s in owner and owner[s] != f}) for f in defs}
    problems = []
    boundary = [f for f in defs if f.endswith("capi/src/api.c")]
    for f, targets in edges.items():
        for b in boundary:
            if b in targets:
                calls = sorted(s for s in uses[f] if owner.get(s) == b)
                problems.append(f"{f} calls the exported boundary {b}: {', '.join(calls)}")
    # Cycles by depth-first search.
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(f: str) -> None:
        state[f] = 1
        stack.append(f)
        for t in edges[f]:
            if state.get(t) == 1:
                cycle = stack[stack.index(t):] + [t]
                problems.append("files call each other in a circle: " + " -> ".join(cycle))
            elif t not in state:
                visit(t)
        stack.pop()
        state[f] = 2

    for f in sorted(edges):
        if f not in state:
            visit(f)
    for p in problems:
        print("layers:", p)
    print(f"layers: {len(defs)} source files, {sum(len(e) for e in edges.values())} file-to-file call edges, "
          f"{len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    # ctest passes $<TARGET_OBJECTS:...> as one ;-separated argument.
    sys.exit(main([o for arg in sys.argv[1:] for o in arg.split(";") if o]))
