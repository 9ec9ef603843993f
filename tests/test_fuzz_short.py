"""Short fuzzing of the Python loaders, as part of `make test` (tests/fuzz/, docs/reliability.md).

Time budget: the whole suite must stay under 15 minutes on 2 cores, so this
file is kept under about 60 s: each of the 9 atheris targets runs for
SECONDS_PER_TARGET (2 s, plus 2-5 s to start), and the seeded truncation and
bit-flip sweep over the seed corpus takes a few seconds. Longer runs:
``make fuzz-python FUZZ_SECONDS=...``.
"""

from __future__ import annotations

import random
import sys
import warnings
from pathlib import Path

import pytest

from penumbra.errors import PenumbraError

FUZZ = Path(__file__).resolve().parent / "fuzz"
sys.path.insert(0, str(FUZZ))
import fuzz_loaders  # noqa: E402

SECONDS_PER_TARGET = 2


@pytest.mark.parametrize("target", fuzz_loaders.TARGETS)
def test_fuzz_target_briefly(target, tmp_path):
    """Any exception that is not a penumbra error, or a process over 2 GB, is a finding."""
    pytest.importorskip("atheris", reason="atheris is not installed (make fuzz-python installs it)")
    result = fuzz_loaders.run_target(target, SECONDS_PER_TARGET, tmp_path)
    output = fuzz_loaders.excerpt(result["output"])
    assert result["returncode"] == 0 and not result["findings"], (
        f"fuzz finding in {target} (inputs in {tmp_path / target / 'findings'}):\n{output}")
    assert result["execs"] > 0


def mutations(data: bytes, rng: random.Random, count: int) -> list[bytes]:
    """Truncations at evenly spread lengths, then single and multiple bit flips."""
    out = [data[:n] for n in sorted({len(data) * k // 16 for k in range(16)})]
    for _ in range(count):
        mutated = bytearray(data)
        for _ in range(rng.choice((1, 1, 2, 8))):
            i = rng.randrange(len(mutated))
            mutated[i] ^= 1 << rng.randrange(8)
        out.append(bytes(mutated))
    return out


@pytest.mark.parametrize("target", fuzz_loaders.TARGETS)
def test_truncated_and_bitflipped_seeds(target, tmp_path):
    """Every truncation and (seeded) bit flip of every seed file loads or raises a penumbra error."""
    loaders = fuzz_loaders._loaders(target)
    rng = random.Random(17)
    path = tmp_path / f"input.{'toml' if target == 'scene' else target}"
    for seed in sorted((fuzz_loaders.CORPUS / target).iterdir()):
        for data in mutations(seed.read_bytes(), rng, 24):
            path.write_bytes(data)
            for load in loaders:
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        load(path)
                except PenumbraError:
                    pass
