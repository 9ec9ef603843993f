"""Atheris (libFuzzer for Python) targets for penumbra's Python loaders.

One target per input format: exr, hdr, npy, png (height and albedo maps), obj,
ply, off, stl (meshes) and scene (TOML scene files). Each writes the fuzzer's
bytes to a file with the format's extension and loads it; a penumbra error
(:class:`penumbra.errors.PenumbraError`, e.g. InputError) is the expected
answer to bad input, any other exception is a finding (libFuzzer stops and
writes the input as ``crash-*``). So is a process that grows beyond
``-rss_limit_mb`` (2048 here): while fuzzing, ``PENUMBRA_MAX_BYTES`` is 256 MiB,
so any allocation that big has escaped the loaders' checks.

Run one target (libFuzzer flags and corpus folders after its name)::

    python tests/fuzz/fuzz_loaders.py --target obj -max_total_time=10 /tmp/new tests/fuzz/corpus/obj

or several (named, or all) with a summary (``make fuzz-python``, ``FUZZ_SECONDS`` each)::

    python tests/fuzz/fuzz_loaders.py --seconds 10 --out build/fuzz-python [TARGET ...]

The seed corpus (tests/fuzz/corpus/<target>/) is made by make_corpus.py.
docs/reliability.md has the figures.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
CORPUS = HERE / "corpus"
FUZZ_MAX_BYTES = str(256 << 20)
RSS_LIMIT_MB = 2048
TARGETS = ("exr", "hdr", "npy", "png", "obj", "ply", "off", "stl", "scene")


def _loaders(target: str) -> list:
    """The functions that load a file of the target's format (imported under atheris' instrumentation);
    each is called on every input."""
    from penumbra import heightfield, imageio, meshio, scenefile

    return {"exr": [imageio.read_envmap, heightfield.load_heights, heightfield.load_albedo],
            "hdr": [imageio.read_envmap],
            "npy": [imageio.read_envmap, heightfield.load_heights, heightfield.load_albedo],
            "png": [heightfield.load_heights, heightfield.load_albedo],
            "scene": [scenefile.load_scene]}.get(target, [meshio.load_mesh])


def fuzz_main(target: str, argv: list[str]) -> None:
    import atheris

    os.environ["PENUMBRA_MAX_BYTES"] = os.environ.get("PENUMBRA_FUZZ_MAX_BYTES", FUZZ_MAX_BYTES)
    with atheris.instrument_imports(include=[f"penumbra.{m}" for m in ("meshio", "imageio", "heightfield", "scenefile",
                                                                        "limits")]):
        import penumbra.heightfield  # noqa: F401
        import penumbra.imageio  # noqa: F401
        import penumbra.meshio  # noqa: F401
        import penumbra.scenefile  # noqa: F401
    from penumbra.errors import PenumbraError

    loaders = _loaders(target)
    # The file each input is written to: in the runner's output folder, else a new temporary folder.
    scratch = os.environ.get("PENUMBRA_FUZZ_SCRATCH")
    folder = Path(scratch) if scratch else Path(tempfile.mkdtemp(prefix=f"penumbra-fuzz-{target}-"))
    path = folder / f"input.{'toml' if target == 'scene' else target}"
    warnings.simplefilter("ignore")  # loaders warn about odd but readable headers; not findings

    def test_one_input(data: bytes) -> None:
        path.write_bytes(data)
        for load in loaders:
            try:
                load(path)
            except PenumbraError:
                pass

    atheris.Setup([sys.argv[0], *argv], test_one_input)
    atheris.Fuzz()


_STATS = re.compile(r"#(\d+)\s+DONE\s+cov: (\d+) ft: (\d+)")
_EXECS = re.compile(r"stat::number_of_executed_units:\s*(\d+)")


def run_target(target: str, seconds: float, out: Path) -> dict:
    """Fuzz one target for ``seconds`` in a subprocess; returns executions, coverage, findings and output."""
    scratch = out / target / "new-corpus"
    artifacts = out / target / "findings"
    scratch.mkdir(parents=True, exist_ok=True)
    artifacts.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, str(Path(__file__).resolve()), "--target", target, f"-max_total_time={int(seconds)}",
               f"-rss_limit_mb={RSS_LIMIT_MB}", "-timeout=20", "-max_len=8192", "-print_final_stats=1",
               f"-artifact_prefix={artifacts}/", str(scratch), str(CORPUS / target)]
    start = time.monotonic()
    env = dict(os.environ, PENUMBRA_FUZZ_SCRATCH=str(out / target))
    proc = subprocess.run(command, capture_output=True, text=True, timeout=seconds + 120, env=env)
    text = proc.stdout + proc.stderr
    stats = _STATS.search(text)
    execs = _EXECS.search(text)
    findings = sorted(p.name for p in artifacts.iterdir())
    return {"target": target, "returncode": proc.returncode, "seconds": round(time.monotonic() - start, 1),
            "execs": int(execs.group(1)) if execs else (int(stats.group(1)) if stats else 0),
            "cov": int(stats.group(2)) if stats else None, "ft": int(stats.group(3)) if stats else None,
            "findings": findings, "output": text}


def excerpt(output: str, size: int = 6000) -> str:
    """The part of a run's output that shows a finding: from the uncaught exception on, else the end."""
    start = output.rfind("=== Uncaught Python exception")
    return output[start:start + size] if start >= 0 else output[-size:]


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--target" and sys.argv[2] in TARGETS:
        fuzz_main(sys.argv[2], sys.argv[3:])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("targets", nargs="*", choices=[[], *TARGETS], default=[], help="default: all")
    parser.add_argument("--seconds", type=float, default=float(os.environ.get("FUZZ_SECONDS", 10)))
    parser.add_argument("--out", type=Path, default=Path("build/fuzz-python"))
    args = parser.parse_args()
    targets = args.targets or TARGETS
    failed = 0
    print(f"{'target':8} {'seconds':>8} {'execs':>9} {'cov':>6} {'ft':>6}  findings")
    for target in targets:
        r = run_target(target, args.seconds, args.out)
        print(f"{target:8} {r['seconds']:8.1f} {r['execs']:9d} {r['cov'] or '-':>6} {r['ft'] or '-':>6}  "
              f"{', '.join(r['findings']) or 'none'}", flush=True)
        if r["returncode"] != 0 or r["findings"]:
            failed += 1
            sys.stderr.write(excerpt(r["output"]) + "\n")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
