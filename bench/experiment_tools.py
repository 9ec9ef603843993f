"""What the experiment scripts of bench/ (fiv_experiments.py,
heightfield_experiments.py) share: timestamped logging, number formatting,
a description of the machine and checkout, the stale-library warning and the
--report-only path."""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parents[1]


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def f4(x) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.4f}"


def git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True).stdout.rstrip("\n")
    except OSError:
        return ""


def machine(version: str) -> dict:
    """CPU, cores, platform, Python, the penumbra version and the checkout's HEAD."""
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
            "penumbra": version, "git_head": git("rev-parse", "--short", "HEAD")}


def library_in_use(sources: list[Path]) -> Path | None:
    """$PENUMBRA_LIBRARY when it is a file, with a warning when any of
    `sources` is newer than it (kernels are embedded at build time)."""
    lib = Path(os.environ.get("PENUMBRA_LIBRARY", ""))
    if not lib.is_file():
        return None
    newest = max((p.stat().st_mtime for p in sources), default=0.0)
    if newest > lib.stat().st_mtime:
        log(f"WARNING: kernels/ or capi/ changed after {lib} was built; rebuild it (cmake --build build/dev)")
    return lib


def rewrite_report(out: Path, report: Callable[[dict], str], write_text: Callable[[Path, str], None]) -> int:
    """--report-only: report.md again from out/results.json."""
    write_text(out / "report.md", report(json.loads((out / "results.json").read_text())))
    return 0


def output_folder(out: str | Path, quick: bool, ignored: str, write_text: Callable[[Path, str], None]) -> Path:
    """The results folder (its quick/ subfolder for smoke runs, which never
    overwrite the real results), with a .gitignore for the machine-made
    caches (`ignored` says what they are) and smoke runs."""
    base = Path(out)
    base.mkdir(parents=True, exist_ok=True)
    if not (base / ".gitignore").exists():
        write_text(base / ".gitignore", f"# {ignored} and smoke runs: never committed\ncache/\nquick/\n")
    folder = base / "quick" if quick else base
    folder.mkdir(parents=True, exist_ok=True)
    return folder
