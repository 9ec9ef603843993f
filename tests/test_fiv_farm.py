"""FIV bake farms on dask.distributed (penumbra.farm, `penumbra bake-fiv
--workers/--scheduler`, docs/farm.md): a 2-worker LocalCluster bakes
meshes x env maps into a cache folder while one worker dies mid-bake;
every file must come out complete and identical to a serial bake, the killed
bake resumed from its checkpoint. Without dask, the farm options say which
pip command installs it, before any work."""

from __future__ import annotations

import os
import signal
import sys
import time

import numpy as np
import pytest

from penumbra import farm, procedural
from penumbra.errors import InputError
from penumbra.meshio import Mesh, save_obj
from penumbra.methods.fiv import FivField, bake_to_cache, read_header

# Small enough for the suite; 24 spheres, so a bake stopped after its first
# leaves most of the work to the resumed run.
OPTIONS = {"samples": [64, 33, 24], "face_size": 16, "sun_supersampling": 1, "precision": "float32"}


def jobs(tmp_path, cache):
    meshes = {"sphere": procedural.sphere(0.5, 2), "torus": procedural.torus(1.0, 0.3, 24, 12)}
    for name, m in meshes.items():
        save_obj(tmp_path / f"{name}.obj", Mesh(m.vertices, m.faces))
    return [{"mesh": str(tmp_path / f"{name}.obj"), "options": OPTIONS, "cache": str(cache), "device": None,
             "env": {"map": "sky", "rotation_deg": rotation, "intensity": 1.0}}
            for name in meshes for rotation in (0.0, 90.0)]


def bake_dying_once(job: dict) -> dict:
    """The farm's job, except that the first run of the job marked ``victim``
    stops its bake after one sphere (the library writes its checkpoint then)
    and kills its own worker process, as a machine lost mid-bake would: the
    nanny restarts the worker and the scheduler runs the job again, which
    must resume from the checkpoint. Deterministic: no timing decides
    whether a checkpoint exists when the worker dies."""
    from pathlib import Path

    from penumbra import _native
    from penumbra.errors import PenumbraError

    if job.get("victim"):
        try:
            fd = os.open(Path(job["cache"]).parent / "killed-once", os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            pass  # the second run: bake to the end
        else:
            os.close(fd)
            try:
                bake_to_cache(job, progress=lambda done, total: done > 0)
            except PenumbraError as exc:
                if exc.status != _native.ERROR_CANCELLED:
                    raise
            os.kill(os.getpid(), signal.SIGKILL)
    return bake_to_cache(job)


def test_killed_worker_resumes_and_files_match_a_serial_bake(tmp_path, ctx):
    distributed = pytest.importorskip("distributed")
    import cloudpickle

    # The workers are other processes, which cannot import this test module:
    # its job function travels by value.
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    farm_dir, serial_dir = tmp_path / "farm", tmp_path / "serial"
    work = jobs(tmp_path, farm_dir)
    work[1] = {**work[1], "victim": True}
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    client = distributed.Client(cluster)
    try:
        results = farm.run(client, bake_dying_once, work)
    finally:
        client.close()
        cluster.close()
        cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert (tmp_path / "killed-once").exists()  # a worker did die mid-bake
    assert len(results) == len(work)
    assert results[1]["resumed_from"] > 0, results  # the killed bake went on from its checkpoint
    assert results[1]["resumed_from"] < OPTIONS["samples"][2]
    # Serial bakes of the same jobs, in this process.
    serial = [bake_to_cache({**j, "cache": str(serial_dir)}) for j in work]
    for f, s in zip(results, serial):
        assert os.path.basename(f["path"]) == os.path.basename(s["path"])
        head = read_header(f["path"])
        assert head["radii_done"] == head["samples"][2], f"{f['path']} is unfinished"
        a, b = FivField.load(ctx, f["path"]), FivField.load(ctx, s["path"])
        ia, ib = a.info(), b.info()
        for k in ("bake_seconds",):  # wall time differs; everything else is the same bake
            ia.pop(k), ib.pop(k)
        assert ia == ib
        assert np.array_equal(a.samples(), b.samples(), equal_nan=True)


def test_farm_options_without_dask_name_the_pip_command(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(InputError, match=r'pip install "dask\[distributed\]"'):
        farm.require_dask()
    from penumbra.cli import main

    save_obj(tmp_path / "s.obj", Mesh(procedural.sphere(0.5, 1).vertices, procedural.sphere(0.5, 1).faces))
    status = main(["bake-fiv", str(tmp_path / "s.obj"), "--env", "sky", "--cache", str(tmp_path / "c"),
                   "--workers", "2"])
    assert status == 2 and 'pip install "dask[distributed]"' in capsys.readouterr().err
    assert not (tmp_path / "c").exists()  # refused before any work


@pytest.mark.parametrize("argv,message", [
    (["{s}", "{s}", "--env", "sky", "-o", "x.pnfiv"], "-o FILE takes one mesh"),
    (["{s}", "--env", "sky", "--workers", "2", "--scheduler", "tcp://x:1"], "not both"),
    (["{s}", "--env", "sky", "--workers", "0"], "--workers 0 must be >= 1"),
    (["{missing}", "--env", "sky", "--cache", "{c}"], "file not found"),
])
def test_bake_fiv_argument_errors(tmp_path, capsys, argv, message):
    from penumbra.cli import main

    save_obj(tmp_path / "s.obj", Mesh(procedural.sphere(0.5, 1).vertices, procedural.sphere(0.5, 1).faces))
    names = {"s": tmp_path / "s.obj", "missing": tmp_path / "missing.obj", "c": tmp_path / "c"}
    assert main(["bake-fiv", *(a.format(**names) for a in argv)]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "c").exists()


def test_a_cluster_without_workers_is_an_error_not_a_hang():
    """A cluster whose workers cannot start (or are all lost) stops the run
    with an error after no_workers_s, instead of waiting for ever."""
    distributed = pytest.importorskip("distributed")
    from penumbra.errors import PenumbraError

    cluster = distributed.LocalCluster(n_workers=0, processes=False, dashboard_address=None)
    client = distributed.Client(cluster)
    try:
        start = time.monotonic()
        with pytest.raises(PenumbraError, match="no workers for 2 s with 3 of 3 jobs left"):
            farm.run(client, abs, [1, 2, 3], no_workers_s=2)
        assert time.monotonic() - start < 60
    finally:
        client.close()
        cluster.close()
