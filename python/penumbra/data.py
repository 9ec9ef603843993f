"""Where penumbra's real test data lives: the meshes and HDR environment maps
of ``../shared/data`` (origin and licences in its ``SOURCES.md``), which are
not part of the repository.

Everything that reads that data (the tests' fixtures, scene files, the
benchmarks) asks :func:`data_dir`, so one variable moves it:

- ``PENUMBRA_DATA``: the data folder (the one holding ``SHA256SUMS``);
- otherwise ``../shared/data`` beside the source checkout (or, for an
  installed package, beside the working directory).

Scene files name data files portably with the ``data:`` prefix
(``map = "data:envmaps/pisa_probulator_256x128.hdr"``, docs/scene-format.md):
:func:`resolve` turns it into a path under :func:`data_dir`, or raises an
InputError saying that the file needs the test data and where it was looked
for. ``PENUMBRA_REQUIRE_DATA=1`` (set by CI) turns the test suite's skips of
data tests into failures.
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import InputError

ENV_VAR = "PENUMBRA_DATA"
REQUIRE_VAR = "PENUMBRA_REQUIRE_DATA"
SCHEME = "data:"
MARKER = "SHA256SUMS"   # present in every copy of the data folder


def _checkout() -> Path | None:
    """The source checkout this package runs from (python/penumbra inside it), if any."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "pyproject.toml").is_file() and (root / "kernels").is_dir() else None


def default_data_dir() -> Path:
    """``../shared/data`` beside the checkout (else beside the working directory)."""
    candidates = [p.parent / "shared" / "data" for p in (_checkout(), Path.cwd()) if p is not None]
    return next((p for p in candidates if (p / MARKER).is_file()), candidates[0])


def data_dir() -> Path:
    """The data folder: ``$PENUMBRA_DATA``, else :func:`default_data_dir`. It may not exist (see :func:`available`)."""
    env = os.environ.get(ENV_VAR, "").strip()
    return Path(env).expanduser().resolve() if env else default_data_dir()


def available() -> bool:
    """Whether :func:`data_dir` holds the data (its ``SHA256SUMS`` is there)."""
    return (data_dir() / MARKER).is_file()


def required() -> bool:
    """Whether a missing data folder is an error rather than a skip (``PENUMBRA_REQUIRE_DATA=1``, CI)."""
    return os.environ.get(REQUIRE_VAR, "").strip() not in ("", "0")


def missing_reason() -> str:
    """One sentence saying that the data is missing, where it was looked for and how to point elsewhere."""
    return (f"needs penumbra's test data (meshes, HDR maps), not found at {data_dir()}: set {ENV_VAR} "
            "to the data folder (default ../shared/data beside the checkout; README, 'Test data')")


def path(relative: str | Path) -> Path:
    """``relative`` (e.g. ``"envmaps/pisa_probulator_256x128.hdr"``) under :func:`data_dir`."""
    return data_dir() / relative


def is_data_ref(value: str) -> bool:
    """Whether a scene-file path uses the ``data:`` prefix."""
    return value.startswith(SCHEME)


def resolve(value: str, base: str | Path, where: str = "") -> str:
    """A scene-file path as an absolute path: ``data:REL`` under :func:`data_dir`
    (InputError naming ``where`` when the data folder is missing), ``~`` expanded,
    other relative paths against ``base`` (the scene file's folder)."""
    if is_data_ref(value):
        rel = value[len(SCHEME):].lstrip("/")
        if not rel:
            raise InputError(f"{where or 'path'} {value!r}: name a file after '{SCHEME}', e.g. data:envmaps/x.hdr")
        if not available():
            raise InputError(f"{where or 'path'} {value!r} {missing_reason()}")
        return str(path(rel))
    try:
        p = Path(value).expanduser()
    except RuntimeError as exc:  # '~name' of no such user (or no home directory)
        raise InputError(f"{where or 'path'} {value!r}: cannot expand '~': {exc}") from None
    return str(p if p.is_absolute() else (Path(base) / p).resolve())


__all__ = ["ENV_VAR", "REQUIRE_VAR", "SCHEME", "available", "data_dir", "default_data_dir", "is_data_ref",
           "missing_reason", "path", "required", "resolve"]
