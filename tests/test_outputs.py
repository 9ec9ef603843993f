"""Small contracts of what penumbra writes and borrows: files follow the
umask (the C writer of .pnfiv bake files as well as Python's atomic writes),
FivField.bake(path=...) says when it reuses a file and refuses or replaces a
file of other inputs, and pyopencl arrays of the wrong dtype are refused as
image and G-buffer buffers."""

from __future__ import annotations

import os
import stat
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
