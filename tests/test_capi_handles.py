"""Handles through the bindings (issue 17, docs/reliability.md): a released
handle is refused with PN_ERROR_INVALID_HANDLE, never used; Python's objects
release once."""

import ctypes

import pytest

from penumbra import _native
from penumbra.errors import InputError, PenumbraError


def _mesh(ctx) -> ctypes.c_void_p:
    h = ctypes.c_void_p()
    _native.call("pn_mesh_create", ctx._h, ctx._h, ctypes.byref(h))
    return h


def test_double_release_is_refused(ctx):
    h = _mesh(ctx)
    _native.call("pn_mesh_release", ctx._h, h)
    with pytest.raises(PenumbraError, match="not a live penumbra object") as info:
        _native.call("pn_mesh_release", ctx._h, h)
    assert info.value.status == _native.ERROR_INVALID_HANDLE
    assert not isinstance(info.value, InputError)  # a programming error, not bad data


def test_use_after_release_is_refused(ctx):
    h = _mesh(ctx)
    _native.call("pn_mesh_release", ctx._h, h)
    with pytest.raises(PenumbraError) as info:
        _native.call("pn_mesh_commit", ctx._h, h)
    assert info.value.status == _native.ERROR_INVALID_HANDLE
    assert _native.lib.pn_status_name(_native.ERROR_INVALID_HANDLE) == b"PN_ERROR_INVALID_HANDLE"


def test_python_objects_close_once(ctx):
    import numpy as np

    import penumbra

    env = penumbra.EnvMap(ctx, np.ones((4, 8, 3), np.float32))
    h = ctypes.c_void_p(env.handle)
    env.close()
    env.close()  # the wrapper forgets its handle: no second release reaches the library
    assert _native.lib.pn_envmap_release(h) == _native.ERROR_INVALID_HANDLE
