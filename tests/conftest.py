"""Shared fixtures: one penumbra context per test session (PoCL CPU unless
PENUMBRA_DEVICE says otherwise), its pyopencl twins, and a builder for small
test kernels compiled from the library's own kernel sources."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import penumbra
from penumbra import data
from penumbra.kernels import expand

# The real test data (penumbra.data: $PENUMBRA_DATA, default ../shared/data
# beside the checkout). Tests reach it through the ``shared_data`` fixture (or
# ``needs_data()``): absent, they skip with one reason; with
# PENUMBRA_REQUIRE_DATA=1 (CI) they fail instead.
SHARED_DATA = data.data_dir()
if data.available():
    # Pinned for the whole session: an installed package (make test) finds the
    # default folder beside the working directory, which tests change.
    os.environ.setdefault(data.ENV_VAR, str(SHARED_DATA))


def needs_data() -> Path:
    """The data folder, or the test skips (fails under PENUMBRA_REQUIRE_DATA=1) when it is absent."""
    if not data.available():
        if data.required():
            pytest.fail(f"{data.REQUIRE_VAR} is set and the test {data.missing_reason()}", pytrace=False)
        pytest.skip(f"{data.missing_reason()}")
    return SHARED_DATA


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
    """The real test data folder (see needs_data)."""
    return needs_data()


def pytest_report_header(config):
    where = SHARED_DATA if data.available() else f"absent ({SHARED_DATA}): data tests skip"
    return (f"penumbra {penumbra.__version__}, library {penumbra._native.library_path}; test data {where}"
            + (f" ({data.REQUIRE_VAR} set: required)" if data.required() else ""))
