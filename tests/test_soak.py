"""The soak's short version (docs/reliability.md; ``make soak`` runs the
full 10,000 frames): 200 frames of the dynamic scene of tests/soak/soak.py in
a process of their own, with the memory bounds, and the instance churn that
once grew a scene's memory with every addition.

Time: the soak takes ~15-25 s on 2 shared cores with PoCL (most of it the
priming renders), the churn ~5 s; the whole suite must stay under 15 minutes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import penumbra as pn
from penumbra import procedural

SOAK = Path(__file__).parent / "soak" / "soak.py"
sys.path.insert(0, str(SOAK.parent))
import soak  # noqa: E402


def test_soak_200_frames(tmp_path):
    """200 frames, 50 of them warm-up. The bounds of a run this short: the C
    heap in use (stable to ~100 bytes per frame here) at 0.25 KiB per frame,
    RSS (page-granular, ~250 KiB of noise over 150 frames) at 8 KiB per frame,
    which still catches any leaked image, G-buffer, mesh or env map."""
    out = tmp_path / "soak.json"
    env = dict(os.environ, PYOPENCL_CTX=os.environ.get("PYOPENCL_CTX", "0"))
    r = subprocess.run([sys.executable, str(SOAK), "--frames", "200", "--bound-kib", "8", "--heap-bound-kib", "0.25",
                        "--json", str(out)], capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    d = json.loads(out.read_text())
    assert d["ok"] and d["frames"] == 200 and d["warmup"] == 50
    assert d["added"] == 200 and d["removed"] == 198 and d["env_changes"] == 7 and d["plan_sets"] == 20
    assert d["python_objects_end"] <= d["python_objects_warm"] + 50, "Python objects pile up"


@pytest.mark.skipif(soak.heap_in_use() is None, reason="needs glibc's mallinfo2 (glibc >= 2.33)")
def test_instance_churn_keeps_memory_flat(ctx):
    """20,000 additions and removals (two instances live) may not grow the C
    heap by more than 256 KiB: a scene kept a 136-byte slot for every id ever
    given out (4.4 MB here). Ids keep counting; removed ones stay invalid."""
    b = procedural.box((0.2, 0.2, 0.2))
    mesh = pn.Mesh(ctx, b.vertices, b.faces, b.normals)
    scene = pn.Scene(ctx)
    live = [scene.add(mesh), scene.add(mesh)]
    scene.commit()
    before = soak.heap_in_use()
    for i in range(20000):
        scene.remove(live[i % 2])
        live[i % 2] = scene.add(mesh, np.hstack([np.eye(3), [[i % 7], [0], [0]]]))
        if i % 100 == 99:
            scene.commit()
    grown = soak.heap_in_use() - before
    assert grown < 256 * 1024, f"the heap grew {grown} bytes ({grown / 20000:.0f} per addition)"
    assert live == [20000, 20001]
    with pytest.raises(pn.PenumbraError):
        scene.set_transform(10000, np.eye(4))
    scene.close()
    mesh.close()
