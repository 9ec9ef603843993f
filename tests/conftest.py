"""Shared fixtures: one penumbra context per test session (PoCL CPU unless
PENUMBRA_DEVICE says otherwise), its pyopencl twins, and a builder for small
test kernels compiled from the library's own kernel sources."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import penumbra
from penumbra.kernels import expand

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def ctx() -> penumbra.Context:
    return penumbra.Context()


@pytest.fixture(scope="session")
def cl_pair(ctx):
    """(pyopencl.Context, pyopencl.CommandQueue) of the session's penumbra context."""
    return ctx.cl_objects()


@pytest.fixture(scope="session")
def build_test_kernel(cl_pair):
    """build(source_with_includes) -> pyopencl.Program, compiled exactly as the library compiles its stages."""
    import pyopencl as cl

    cl_ctx, _ = cl_pair
    cache: dict[str, cl.Program] = {}

    def build(source: str):
        if source not in cache:
            cache[source] = cl.Program(cl_ctx, expand("common/math.cl", source)).build(options=["-cl-std=CL1.2"])
        return cache[source]

    return build


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not (SHARED_DATA / "SHA256SUMS").is_file():
        pytest.fail(f"test data not found at {SHARED_DATA} (the project expects ../shared/data beside the checkout)")
    return SHARED_DATA


def pytest_report_header(config):
    return f"penumbra {penumbra.__version__}, library {penumbra._native.library_path}"
