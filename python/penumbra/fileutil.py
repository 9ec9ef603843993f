"""Small file-system helpers shared by penumbra's readers and writers.

* :func:`atomic_write` / :func:`atomic_write_text` write a file so that an
  interrupted or failed write never destroys (or half-overwrites) an existing
  file: the data goes to a temporary file in the destination directory, which
  then replaces the destination in one ``os.replace``.
* :func:`captured_native_output` temporarily redirects the process-level
  stdout/stderr file descriptors, so that diagnostics printed by native
  libraries (libigl, OpenEXR) can be turned into exception messages instead of
  appearing as stray console text.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import secrets
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_text", "captured_native_output", "NativeOutput"]


def _create_temp_file(directory: Path, name: str, suffix: str) -> Path:
    """Create an empty, exclusively owned temporary file next to the destination.

    ``tempfile.mkstemp`` would create it with mode 0600, and ``os.replace``
    keeps the temporary's mode, so every written image would end up private to
    its owner. Opening with mode 0666 lets the process umask decide, exactly as
    for a file created by ``open(path, "w")``.
    """
    for _ in range(100):
        candidate = directory / f".{name}.{secrets.token_hex(6)}.tmp{suffix}"
        try:
            fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return candidate
    raise FileExistsError(f"could not create a unique temporary file in {directory}")


def _fsync_file(path: Path) -> None:
    """Flush a finished temporary file to disk before it replaces the destination.

    Without this, a power loss shortly after ``os.replace`` can leave the
    destination name pointing at an empty file on some file systems.
    """
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # not supported on this file system; the replace is still atomic
    finally:
        os.close(fd)


def atomic_write(path: str | os.PathLike, write_fn: Callable[[str], object], suffix: str | None = None) -> Path:
    """Write ``path`` atomically through a temporary file in the same directory.

    ``write_fn(tmp_path)`` must write the complete file at ``tmp_path`` (a
    ``str``; it exists and is empty when ``write_fn`` is called). This suits
    libraries that only accept a file name. When ``write_fn`` returns, the
    temporary file is flushed to disk and moved over ``path`` with
    ``os.replace``, which is atomic within one file system, so readers see
    either the old file or the complete new one.

    If ``write_fn`` raises (including ``KeyboardInterrupt``), the temporary file
    is removed, any existing file at ``path`` is left untouched, and the
    exception propagates. Missing parent directories are created.

    ``suffix`` is the temporary file's extension; by default it is ``path``'s
    own suffix, because some writers pick the file format from the extension.

    Returns ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    directory = path.parent
    directory.mkdir(parents=True, exist_ok=True)
    tmp = _create_temp_file(directory, path.name, path.suffix if suffix is None else suffix)
    try:
        write_fn(str(tmp))
        _fsync_file(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | os.PathLike, text: str, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_write`)."""

    def write(tmp_path: str) -> None:
        with open(tmp_path, "w", encoding=encoding) as f:
            f.write(text)

    return atomic_write(path, write)


class NativeOutput:
    """What native code printed inside :func:`captured_native_output` (``text``)."""

    def __init__(self) -> None:
        self.text = ""


def _flush_c_stdio() -> None:
    """Flush the C library's stdio buffers so buffered native output lands in the capture."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):
        pass  # no C runtime reachable this way (e.g. Windows); nothing buffered we can flush


@contextlib.contextmanager
def captured_native_output() -> Iterator[NativeOutput]:
    """Redirect the process's stdout and stderr file descriptors into a buffer.

    Native readers (libigl, OpenEXR) print their diagnostics straight to file
    descriptors 1 and 2, bypassing ``sys.stdout``/``sys.stderr``. Inside this
    context that output is collected; afterwards it is available as the
    yielded object's ``text`` so the caller can quote it in an exception or
    pass it on.

    The redirection is process-wide: output that another thread writes to the
    same descriptors during the (short) native call is captured too, so callers
    should forward text they do not recognise rather than drop it. If the
    descriptors cannot be duplicated (no console at all), nothing is captured.
    """
    result = NativeOutput()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    try:
        saved = (os.dup(1), os.dup(2))
    except OSError:
        yield result
        return
    with tempfile.TemporaryFile() as buffer:
        try:
            os.dup2(buffer.fileno(), 1)
            os.dup2(buffer.fileno(), 2)
            yield result
        finally:
            _flush_c_stdio()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            buffer.seek(0)
            result.text = buffer.read().decode("utf-8", errors="replace")
