"""The experiment harness of bench/: what every experiment script
(fiv_experiments.py, heightfield_experiments.py) runs on.

A script is a definition file: a `Suite` naming its experiments
(`Experiment`: key, title, the function that runs it), its `Runner` subclass
(how it builds scenes and renders), its report and its extra options; the
harness does the rest:

- the command line (--quick, --only, --out, --report-only, --png-size and the
  suite's own options) and the run loop: results.json merged per experiment
  (--only updates its experiments), report.md rewritten from it after each one;
- the output folder (quick/ for smoke runs, a .gitignore for caches) and the
  cache folder;
- the ground-truth cache (`ReferenceCache`: images keyed by a hash of what
  they depend on, the render's seconds beside them);
- evaluation (`metrics`: penumbra.metrics.compare plus the signed error),
  timing (`median_ms`) and images (`Pictures`: results, references and error
  heat maps as small PNGs);
- the record of the machine and checkout, logging and number formatting.

Penumbra functions used here: penumbra.core.Context, penumbra.metrics.compare,
penumbra.metrics.error_heatmap, penumbra.imageio.write_png,
penumbra.fileutil.atomic_write / atomic_write_text and penumbra.__version__.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import hashlib
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np

REPO = Path(__file__).resolve().parents[1]
KERNELS = REPO / "kernels"
if str(REPO / "python") not in sys.path:
    sys.path.insert(0, str(REPO / "python"))

import penumbra  # noqa: E402
from penumbra.fileutil import atomic_write, atomic_write_text  # noqa: E402
from penumbra.imageio import write_png  # noqa: E402
from penumbra.metrics import compare, error_heatmap  # noqa: E402

HEAT_FRACTION = 0.1   # heat maps saturate at this fraction of the reference's range over the evaluated pixels


# --------------------------------------------------------------------------- #
# Definitions
# --------------------------------------------------------------------------- #

@dataclass(frozen=True)
class Variant:
    """One rendering to evaluate: a label (its row and file names), the
    method's parameters, and optionally the method and the group it belongs
    to in a sweep."""
    label: str
    params: dict = field(default_factory=dict)
    method: str = ""
    group: str = ""


def settings(name: str, values: Iterable, **fixed) -> tuple[Variant, ...]:
    """One variant per value of parameter `name` (labels 'name=value', group
    `name`), each with the `fixed` parameters as well."""
    return tuple(Variant(f"{name}={v}", {name: v, **fixed}, group=name) for v in values)


@dataclass(frozen=True)
class Experiment:
    """One experiment of a suite: `run(runner)` returns its results dict
    (stored under results.json's "experiments"/key)."""
    key: str
    title: str
    run: Callable[["Runner"], dict]


@dataclass
class Suite:
    """What a definition file gives the harness."""
    script: str                                   # e.g. "bench/fiv_experiments.py" (named in the report)
    description: str                              # the --help text (the script's docstring)
    experiments: tuple[Experiment, ...]
    runner: Callable[[argparse.Namespace], "Runner"]
    report: Callable[[dict], str]
    default_out: str                              # relative to the repository root
    meta: Callable[["Runner"], dict]              # results.json "meta" beyond date, device and machine
    stamp: Callable[[dict], dict] = lambda meta: {}   # written into each experiment's results
    machine: Callable[[], dict] = lambda: {}      # more about the machine and checkout
    add_arguments: Callable[[argparse.ArgumentParser], None] = lambda ap: None
    quick_help: str = "smoke run"

    @property
    def titles(self) -> dict[str, str]:
        return {e.key: e.title for e in self.experiments}


# --------------------------------------------------------------------------- #
# Logging, formatting, the machine
# --------------------------------------------------------------------------- #

def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def f4(x) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.4f}"


def fmt_params(p: dict) -> str:
    return ", ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items()) or "defaults"


def link(label: str, path: str | None) -> str:
    return f"[{label}]({path})" if path else ""


def git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True).stdout.rstrip("\n")
    except OSError:
        return ""


def sha(path: Path, n: int = 16) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:n]


def machine() -> dict:
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
            "penumbra": penumbra.__version__, "git_head": git("rev-parse", "--short", "HEAD")}


def uncommitted(*paths: str) -> list[str]:
    """Files under `paths` with uncommitted changes."""
    return [line[3:] for line in git("status", "--porcelain", "--", *paths).splitlines() if line.strip()]


def library_sources() -> list[Path]:
    return list(KERNELS.rglob("*.cl")) + list((REPO / "capi").rglob("*.[ch]"))


def library_in_use(sources: Iterable[Path] | None = None) -> Path | None:
    """$PENUMBRA_LIBRARY when it is a file, with a warning when any of
    `sources` (default: kernels/ and capi/) is newer than it (kernels are
    embedded at build time)."""
    lib = Path(os.environ.get("PENUMBRA_LIBRARY", ""))
    if not lib.is_file():
        return None
    newest = max((p.stat().st_mtime for p in (library_sources() if sources is None else sources)), default=0.0)
    if newest > lib.stat().st_mtime:
        log(f"WARNING: kernels/ or capi/ changed after {lib} was built; rebuild it (cmake --build build/dev)")
    return lib


def kernel_hash(include: Callable[[str], bool], names_from: Path = KERNELS) -> str:
    """Hash of the kernel sources a cached product depends on: every
    kernels/**/*.cl whose path relative to kernels/ passes `include`, each
    hashed with its path relative to `names_from` and its bytes."""
    h = hashlib.sha256()
    for p in sorted(KERNELS.rglob("*.cl")):
        if include(p.relative_to(KERNELS).as_posix()):
            h.update(p.relative_to(names_from).as_posix().encode())
            h.update(p.read_bytes())
    return h.hexdigest()[:12]


def key_of(obj) -> str:
    """16 hex digits of the SHA-256 of a string, or of an object's sorted JSON."""
    text = obj if isinstance(obj, str) else json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# --------------------------------------------------------------------------- #
# Ground-truth cache
# --------------------------------------------------------------------------- #

class ReferenceCache:
    """Reference images in `folder`, as reference-<key_of(key)>.npy with a
    .json beside it holding the render's seconds (and what the caller adds).
    The key must hold everything the image depends on (scene, settings,
    kernel sources)."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.hits = self.misses = 0

    def path(self, key) -> Path:
        return self.folder / f"reference-{key_of(key)}.npy"

    def get(self, key, render: Callable[[], np.ndarray], record: dict | None = None) -> tuple[np.ndarray, float]:
        """(image, seconds its render took): from the cache, or `render()`
        now and stored (float32) with {"seconds", **record}."""
        path = self.path(key)
        meta = path.with_suffix(".json")
        if path.exists():
            self.hits += 1
            return np.load(path), json.loads(meta.read_text())["seconds"] if meta.exists() else float("nan")
        self.misses += 1
        t0 = time.perf_counter()
        img = np.asarray(render(), dtype=np.float32)
        seconds = time.perf_counter() - t0

        def save(tmp):
            with open(tmp, "wb") as fh:
                np.save(fh, img)
        atomic_write(path, save)
        atomic_write_text(meta, json.dumps({"seconds": seconds, **(record or {})}, default=str))
        return img, seconds


# --------------------------------------------------------------------------- #
# Evaluation, timing, images
# --------------------------------------------------------------------------- #

def metrics(ref: np.ndarray, img: np.ndarray, mask: np.ndarray,
            keys: tuple[str, ...] = ("nrmse", "rel_rms", "max_abs", "bias")) -> dict:
    """penumbra.metrics.compare of `img` against `ref` over `mask`, plus
    mean_error (signed mean over the evaluated pixels, negative: too dark) and
    bias (mean_error / the reference's range there); the `keys` asked for."""
    m = compare(ref, img, mask)
    if "mean_error" in keys or "bias" in keys:
        m["mean_error"] = float(np.mean(img[mask] - ref[mask]))
    if "bias" in keys:
        m["bias"] = m["mean_error"] / float(ref[mask].max() - ref[mask].min())
    return {k: m[k] for k in keys}


def median_ms(fn: Callable[[], Any], runs: int, finish: Callable[[], Any] | None = None,
              warmup: int = 0) -> tuple[float, list[float]]:
    """(median, all) wall-clock milliseconds of `runs` calls of `fn` (each
    followed by `finish`), after `warmup` untimed calls."""
    times = []
    for k in range(warmup + runs):
        t0 = time.perf_counter()
        fn()
        if finish is not None:
            finish()
        if k >= warmup:
            times.append(1000.0 * (time.perf_counter() - t0))
    return statistics.median(times), times


def shrink(img: np.ndarray, size: int) -> np.ndarray:
    """Box-filters a (H, W, C) image down by an integer factor to at most `size` pixels wide (small PNGs)."""
    f = max(1, img.shape[1] // max(size, 1))
    if f == 1:
        return img
    h, w = img.shape[0] // f * f, img.shape[1] // f * f
    return img[:h, :w].reshape(h // f, f, w // f, f, -1).mean(axis=(1, 3))


def exposure(ref: np.ndarray, mask: np.ndarray) -> float:
    """The PNGs' exposure: the 99th percentile of the reference's mean over `mask` maps to 0.85."""
    p99 = float(np.percentile(ref[mask].mean(axis=1), 99.0)) if mask.any() else 1.0
    return math.log2(0.85 / max(p99, 1e-12))


def heat_scale(ref: np.ndarray, mask: np.ndarray) -> float:
    return HEAT_FRACTION * float(ref[mask].max() - ref[mask].min())


def file_label(label: str) -> str:
    """A variant label as a file-name part ('exact FIV+' -> 'exact_FIVplus')."""
    return "".join(ch for ch in label.replace(" ", "_").replace("+", "plus") if ch.isalnum() or ch in "_-")


class Pictures:
    """Small PNGs in `folder` (box-filtered down to at most `size` pixels wide)."""

    def __init__(self, folder: Path, size: int = 256):
        self.folder, self.size = Path(folder), size

    def image(self, name: str, img: np.ndarray, exp: float = 0.0) -> str:
        write_png(self.folder / name, shrink(img, self.size), exp)
        return name

    def result(self, stem: str, label: str, ref: np.ndarray, img: np.ndarray, mask: np.ndarray, exp: float,
               heat: float, error_only: bool = False) -> tuple[str | None, str]:
        """stem_<label>.png (unless error_only) and its heat map stem_<label>_error.png: their names."""
        name = f"{stem}_{file_label(label)}"
        png = None if error_only else self.image(f"{name}.png", img, exp)
        return png, self.image(f"{name}_error.png", error_heatmap(ref, img, mask, heat))

    def set(self, stem: str, ref: np.ndarray, images: dict[str, np.ndarray], mask: np.ndarray,
            errors_only: tuple[str, ...] = (), reference: bool = True) -> dict:
        """stem_reference.png (unless reference=False) and each image with its heat map, exposure and heat
        scale from the reference over `mask`: the file names by label ('<label>_error' for the maps)."""
        exp, heat = exposure(ref, mask), heat_scale(ref, mask)
        out = {}
        if reference:
            out["reference"] = self.image(f"{stem}_reference.png", ref, exp)
        for label, img in images.items():
            png, err = self.result(stem, label, ref, img, mask, exp, heat, label in errors_only)
            if png:
                out[label] = png
            out[f"{label}_error"] = err
        return out


# --------------------------------------------------------------------------- #
# Runner and the command line
# --------------------------------------------------------------------------- #

def output_folder(out: str | Path, quick: bool, ignored: str = "reference images (machine-made, cached)") -> Path:
    """The results folder (its quick/ subfolder for smoke runs, which never
    overwrite the real results), with a .gitignore for the machine-made
    caches (`ignored` says what they are) and smoke runs."""
    base = Path(out)
    base.mkdir(parents=True, exist_ok=True)
    if not (base / ".gitignore").exists():
        atomic_write_text(base / ".gitignore", f"# {ignored} and smoke runs: never committed\ncache/\nquick/\n")
    folder = base / "quick" if quick else base
    folder.mkdir(parents=True, exist_ok=True)
    return folder


class Runner:
    """What every suite's runner has: the arguments, the output folder, the
    cache folder (cache_env: a subfolder of $PENUMBRA_CACHE when that is set;
    else OUT/cache), an OpenCL context, the reference cache and the PNG
    writer."""
    cached = "reference images (machine-made, cached)"
    cache_env: str | None = None

    def __init__(self, args: argparse.Namespace):
        from penumbra.core import Context

        self.args = args
        self.quick = args.quick
        self.out = output_folder(args.out, args.quick, self.cached)
        env_cache = os.environ.get("PENUMBRA_CACHE") if self.cache_env else None
        self.cache = Path(env_cache) / self.cache_env if env_cache else Path(args.out) / "cache"
        self.cache.mkdir(parents=True, exist_ok=True)
        self.references = ReferenceCache(self.cache)
        self.pictures = Pictures(self.out, getattr(args, "png_size", 256))
        self.library: Path | None = None
        self.ctx = Context()


def rewrite_report(folder: Path, report: Callable[[dict], str]) -> int:
    """--report-only: report.md again from folder/results.json."""
    atomic_write_text(folder / "report.md", report(json.loads((folder / "results.json").read_text())))
    return 0


def parser(suite: Suite) -> argparse.ArgumentParser:
    keys = ",".join(e.key for e in suite.experiments)
    ap = argparse.ArgumentParser(description=suite.description.split("\n\n")[0],
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=suite.quick_help)
    ap.add_argument("--out", default=str(REPO / suite.default_out))
    ap.add_argument("--only", default="", help=f"comma-separated experiments ({keys})")
    ap.add_argument("--report-only", action="store_true", help="rewrite report.md from results.json")
    ap.add_argument("--png-size", type=int, default=256, help="PNGs are box-filtered down to at most this width")
    suite.add_arguments(ap)
    return ap


def main(suite: Suite, argv=None) -> int:
    ap = parser(suite)
    args = ap.parse_args(argv)
    by_key = {e.key: e for e in suite.experiments}
    only = [s.strip() for s in args.only.split(",") if s.strip()] or list(by_key)
    for s in only:
        if s not in by_key:
            ap.error(f"unknown experiment {s!r} (one of {', '.join(by_key)})")
    lib = library_in_use()
    if args.report_only:
        return rewrite_report(Path(args.out) / ("quick" if args.quick else ""), suite.report)
    run = suite.runner(args)
    run.library = lib
    path = run.out / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {"experiments": {}}
    results["meta"] = {"date": _dt.date.today().isoformat(), "device": run.ctx.device_name,
                       "machine": {**machine(), **suite.machine()}, **suite.meta(run)}
    for s in only:
        e = by_key[s]
        log(f"experiment {s}: {e.title}")
        t0 = time.perf_counter()
        results["experiments"][s] = e.run(run)
        results["experiments"][s]["seconds"] = time.perf_counter() - t0
        results["experiments"][s].update(suite.stamp(results["meta"]))
        atomic_write_text(path, json.dumps(results, indent=1, default=float))
        atomic_write_text(run.out / "report.md", suite.report(results))
        log(f"experiment {s} done in {time.perf_counter() - t0:.0f} s")
    return 0
