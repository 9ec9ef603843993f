"""Small contracts of what penumbra writes and borrows: files follow the
umask (the C writer of .pnfiv bake files as well as Python's atomic writes),
FivField.bake(path=...) says when it reuses a file and refuses or replaces a
file of other inputs, and pyopencl arrays of the wrong dtype are refused as
image and G-buffer buffers."""

from __future__ import annotations

import os
import stat
import time
import warnings

import numpy as np
import pytest

from penumbra import procedural
from penumbra.core import EnvMap, GBuffer, Image, Mesh
from penumbra.errors import InputError
from penumbra.fileutil import atomic_write_text
from penumbra.imageio import write_png
from penumbra.methods.fiv import FivField, FivOptions, FivReuseWarning, read_header

OPTS = FivOptions(samples=(8, 5, 4), face_size=8, sun_supersampling=1)


@pytest.fixture(scope="module")
def env(ctx):
    return EnvMap(ctx, procedural.sky(64, 32), face_size=8, irradiance_face_size=8)


@pytest.fixture(scope="module")
def sphere(ctx):
    m = procedural.sphere(0.5, 1)
    return Mesh(ctx, m.vertices, m.faces, m.normals)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_written_files_follow_the_umask(tmp_path, env, sphere, umask):
    old = os.umask(umask)
    try:
        FivField.bake(env, sphere, OPTS, path=tmp_path / "s.pnfiv")           # the C writer
        atomic_write_text(tmp_path / "r.json", "{}\n")                        # Python's atomic writes
        write_png(tmp_path / "i.png", np.zeros((2, 2, 3), np.float32))
    finally:
        os.umask(old)
    for name in ("s.pnfiv", "r.json", "i.png"):
        assert _mode(tmp_path / name) == 0o666 & ~umask, name
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]        # no temporary file left behind


def test_bake_says_it_reused_a_finished_file(tmp_path, env, sphere):
    path = tmp_path / "s.pnfiv"
    first = FivField.bake(env, sphere, OPTS, path=path)
    assert first.baked_now and not first.reused
    before = path.read_bytes()
    with pytest.warns(FivReuseWarning, match="loaded it instead of baking"):
        again = FivField.bake(env, sphere, OPTS, path=path)
    assert again.reused and not again.baked_now and path.read_bytes() == before
    np.testing.assert_array_equal(again.samples(), first.samples())
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # quiet: a cache's hit is silent
        assert FivField.bake(env, sphere, OPTS, path=path, quiet=True).reused


def test_bake_refuses_a_file_of_other_inputs_or_replaces_it_when_asked(tmp_path, ctx, env, sphere):
    path = tmp_path / "s.pnfiv"
    FivField.bake(env, sphere, OPTS, path=path)
    before = path.read_bytes()
    other = FivOptions(samples=(9, 5, 4), face_size=8, sun_supersampling=1)
    with pytest.raises(InputError, match="other options"):
        FivField.bake(env, sphere, other, path=path)
    box = procedural.box((0.5, 0.5, 0.5))
    with pytest.raises(InputError, match="another mesh"):
        FivField.bake(env, Mesh(ctx, box.vertices, box.faces, box.normals), OPTS, path=path)
    assert path.read_bytes() == before                                    # left alone
    fresh = FivField.bake(env, sphere, other, path=path, reuse=False)
    assert fresh.baked_now and not fresh.reused
    assert list(read_header(path)["samples"]) == [9, 5, 4]


def test_wrong_dtype_pyopencl_arrays_are_refused(ctx, cl_pair):
    import pyopencl.array as cla
    import pyopencl.cltypes as cltypes

    _, queue = cl_pair
    w, h = 8, 4
    with pytest.raises(InputError, match="image buffer.*float64.*float32"):
        Image(ctx, w, h, buffer=cla.zeros(queue, (h, w, 4), np.float64))
    with pytest.raises(InputError, match="image buffer.*int32"):
        Image(ctx, w, h, buffer=cla.zeros(queue, (h, w, 4), np.int32))
    Image(ctx, w, h, buffer=cla.zeros(queue, (h, w), cltypes.float4))       # float4 vectors are float32

    def planes(**dtypes):
        out = {p: cla.zeros(queue, (h, w, 4), dtypes.get(p, np.float32)) for p in ("position", "normal", "albedo",
                                                                                      "material")}
        out["instance"] = cla.zeros(queue, (h, w), dtypes.get("instance", np.uint32))
        return out

    GBuffer(ctx, w, h, planes=planes())
    with pytest.raises(InputError, match="G-buffer plane normal.*float64"):
        GBuffer(ctx, w, h, planes=planes(normal=np.float64))
    with pytest.raises(InputError, match="G-buffer plane instance.*float32.*uint32"):
        GBuffer(ctx, w, h, planes=planes(instance=np.float32))
    with pytest.raises(InputError, match="not contiguous"):
        Image(ctx, w, h, buffer=cla.zeros(queue, (h, 2 * w, 4), np.float32)[:, ::2])


# ---------------------------------------------------------------- the output policy (docs/reliability.md)


def _dead_pid() -> int:
    """The process id of a process that has exited (and been reaped)."""
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def _age(path, seconds: float) -> None:
    t = time.time() - seconds
    os.utime(path, (t, t))


@pytest.mark.parametrize("kind", ["fifo", "folder", "link to a device", "link to a folder"])
def test_outputs_refuse_targets_that_are_not_regular_files(tmp_path, kind):
    target = tmp_path / "out.json"
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "folder":
        target.mkdir()
    elif kind == "link to a device":
        target.symlink_to(os.devnull)
    else:
        (tmp_path / "d").mkdir()
        target.symlink_to(tmp_path / "d")
    before = os.lstat(target)
    with pytest.raises(InputError, match="replaces only regular files"):
        atomic_write_text(target, "{}\n")
    after = os.lstat(target)
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)     # the node itself is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out.json"] + (["d"] if kind.endswith("folder")
                                                                               and "link" in kind else []))


def test_outputs_under_a_file_are_refused(tmp_path):
    (tmp_path / "f").write_text("a file")
    with pytest.raises(InputError, match="is a file, not a folder"):
        atomic_write_text(tmp_path / "f" / "x.json", "{}\n")
    with pytest.raises(InputError, match="is a file, not a folder"):
        atomic_write_text(tmp_path / "f" / "sub" / "x.json", "{}\n")
    assert (tmp_path / "f").read_text() == "a file"


def test_outputs_follow_symbolic_links(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real.name)
    atomic_write_text(link, "new")
    assert link.is_symlink() and os.readlink(link) == real.name              # the link stays a link
    assert real.read_text() == "new"
    dangling = tmp_path / "dangling.json"
    dangling.symlink_to("made.json")
    atomic_write_text(dangling, "made")
    assert dangling.is_symlink() and (tmp_path / "made.json").read_text() == "made"
    assert not [p for p in tmp_path.iterdir() if ".tmp" in p.name]


def test_all_or_nothing_writes_every_output_or_none(tmp_path):
    from penumbra.fileutil import all_or_nothing

    a, b = tmp_path / "a.txt", tmp_path / "b.png"
    a.write_text("old a")
    b.write_text("old b")
    with pytest.raises(InputError, match="exposure must be finite"):
        with all_or_nothing():
            atomic_write_text(a, "new a")
            assert a.read_text() == "old a"                                   # not yet: at the end of the block
            write_png(b, np.zeros((2, 2, 3), np.float32), exposure=float("nan"))
    assert (a.read_text(), b.read_text()) == ("old a", "old b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.png"]   # the temporaries are gone
    with pytest.raises(KeyboardInterrupt):
        with all_or_nothing():
            atomic_write_text(a, "new a")
            raise KeyboardInterrupt
    assert a.read_text() == "old a" and sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.png"]
    with all_or_nothing():
        atomic_write_text(a, "new a")
        write_png(b, np.zeros((2, 2, 3), np.float32))
        with pytest.raises(InputError, match="more than one output"):
            atomic_write_text(a, "again")
    assert a.read_text() == "new a" and b.read_bytes().startswith(b"\x89PNG")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.png"]


def test_stale_temporaries_of_a_target_are_removed_on_its_next_write(tmp_path):
    from penumbra.fileutil import STALE_AGE_SECONDS, STALE_GRACE_SECONDS

    dead = _dead_pid()
    target = tmp_path / "x.exr"
    stale = [tmp_path / f".x.exr.tmp-{dead}-0123456789ab.exr",          # Python's, writer dead
             tmp_path / f"x.exr.tmp-{dead}-7",                          # the library's checkpoint, writer dead
             tmp_path / f".x.exr.tmp-{os.getppid()}-0123456789ab.exr",  # writer alive, but not touched for a day
             tmp_path / ".x.exr.0123456789ab.tmp.exr"]                  # an older version's, a day old
    kept = [tmp_path / f".x.exr.tmp-{dead}-fedcba987654.exr",           # writer dead, but just written (grace)
            tmp_path / f".x.exr.tmp-{os.getppid()}-00000000aaaa.exr",   # writer alive
            tmp_path / f".y.exr.tmp-{dead}-0123456789ab.exr",           # another target's
            tmp_path / "x.exr.tmp-notes"]                               # not ours
    for p in stale + kept:
        p.write_text("partial")
    for p in stale[:2]:
        _age(p, STALE_GRACE_SECONDS + 5)
    for p in stale[2:]:
        _age(p, STALE_AGE_SECONDS + 5)
    atomic_write_text(target, "new")
    assert target.read_text() == "new"
    assert [p.name for p in stale if p.exists()] == []
    assert [p.name for p in kept if not p.exists()] == []


def test_a_killed_writers_temporary_file_is_removed_by_the_next_write(tmp_path):
    """SIGKILL during an atomic write leaves its temporary file; the next write to the target removes it."""
    import signal
    import subprocess
    import sys

    from penumbra.fileutil import STALE_GRACE_SECONDS

    target = tmp_path / "out.json"
    code = ("import sys, time; from pathlib import Path; from penumbra.fileutil import atomic_write\n"
            "def slow(tmp):\n    Path(tmp).write_text('partial'); print('writing', flush=True); time.sleep(600)\n"
            f"atomic_write({str(target)!r}, slow)\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "writing"
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait()
    left = [q for q in tmp_path.iterdir() if q.name != "out.json"]
    assert len(left) == 1 and f".tmp-{p.pid}-" in left[0].name and not target.exists()
    _age(left[0], STALE_GRACE_SECONDS + 5)
    atomic_write_text(target, "{}\n")
    assert sorted(q.name for q in tmp_path.iterdir()) == ["out.json"]


def test_bake_removes_a_dead_checkpoints_temporary_file(tmp_path, env, sphere):
    from penumbra.fileutil import STALE_GRACE_SECONDS

    path = tmp_path / "b.pnfiv"
    left = tmp_path / f"b.pnfiv.tmp-{_dead_pid()}-0"          # the library's checkpoint temporary, writer killed
    left.write_bytes(b"PNFIV partial")
    _age(left, STALE_GRACE_SECONDS + 5)
    FivField.bake(env, sphere, OPTS, path=path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.pnfiv"]


def test_bake_follows_links_and_refuses_other_nodes(tmp_path, env, sphere):
    link = tmp_path / "link.pnfiv"
    link.symlink_to("real.pnfiv")                            # dangling: the bake creates the file it names
    assert FivField.bake(env, sphere, OPTS, path=link).baked_now
    assert link.is_symlink() and read_header(tmp_path / "real.pnfiv")["radii_done"] == OPTS.samples[2]
    fifo = tmp_path / "f.pnfiv"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="is a FIFO"):
        FivField.bake(env, sphere, OPTS, path=fifo)
    dev = tmp_path / "null.pnfiv"
    dev.symlink_to(os.devnull)
    with pytest.raises(InputError, match="is a device"):
        FivField.bake(env, sphere, OPTS, path=dev)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode) and dev.is_symlink()


def test_a_fresh_bake_under_a_black_env_map_is_baked_now(tmp_path, ctx, sphere):
    black = EnvMap(ctx, np.zeros((32, 64, 3), np.float32), face_size=8, irradiance_face_size=8)
    path = tmp_path / "black.pnfiv"
    fresh = FivField.bake(black, sphere, OPTS, path=path)
    assert fresh.baked_now and not fresh.reused
    with pytest.warns(FivReuseWarning):
        again = FivField.bake(black, sphere, OPTS, path=path)
    assert again.reused and not again.baked_now
    assert FivField.bake(black, sphere, OPTS, path=path, reuse=False).baked_now
    assert FivField.bake(black, sphere, OPTS).baked_now                      # no file at all


def test_a_released_context_is_freed_without_the_cycle_collector():
    import gc
    import weakref

    from penumbra.core import Context

    enabled = gc.isenabled()
    gc.disable()
    try:
        c = Context()
        assert c._ctx is c
        ref = weakref.ref(c)
        del c
        assert ref() is None          # reference counting alone frees it (no cycle through itself)
    finally:
        if enabled:
            gc.enable()
