"""Small file-system helpers shared by penumbra's readers and writers.

* :func:`atomic_write` / :func:`atomic_write_text` write a file so that an
  interrupted or failed write never destroys (or half-overwrites) an existing
  file: the data goes to a temporary file in the destination directory, which
  then replaces the destination in one ``os.replace``. Inside
  :func:`all_or_nothing` the replacements wait until the block succeeds, so a
  command's outputs appear together or not at all.
* :func:`output_target` is the output policy (docs/reliability.md):
  an existing target that is not a regular file (a directory, a device, a
  FIFO, a socket) is refused; a symbolic link is followed, and the file it
  names is replaced (the link stays).
* :func:`remove_stale_temporaries` removes temporary files of earlier writes
  to a target whose writer died (SIGKILL, power loss).
* :func:`captured_native_output` temporarily redirects the process-level
  stdout/stderr file descriptors, so that diagnostics printed by native
  libraries (libigl, OpenEXR) can be turned into exception messages instead of
  appearing as stray console text.
"""

from __future__ import annotations

import contextlib
import contextvars
import ctypes
import errno
import os
import re
import secrets
import stat
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from .errors import InputError

__all__ = ["atomic_write", "atomic_write_text", "all_or_nothing", "output_target", "remove_stale_temporaries",
           "captured_native_output", "NativeOutput", "STALE_GRACE_SECONDS", "STALE_AGE_SECONDS"]

# A temporary file of ours whose writer (a process id of this host) is dead is
# removed once it has not been modified for this long: a writer on another host
# sharing the folder (a farm's cache) may have the process id of a dead local
# process, but its temporary file is being written, so its time is recent.
STALE_GRACE_SECONDS = 30.0
# A temporary file of ours not modified for this long is removed whatever its process id says.
STALE_AGE_SECONDS = 24 * 3600.0


def _temp_name(name: str, suffix: str) -> str:
    """``.<name>.tmp-<pid>-<12 hex digits><suffix>``: recognisable (remove_stale_temporaries) and hidden."""
    return f".{name}.tmp-{os.getpid()}-{secrets.token_hex(6)}{suffix}"


def _create_temp_file(directory: Path, name: str, suffix: str) -> Path:
    """Create an empty, exclusively owned temporary file next to the destination.

    ``tempfile.mkstemp`` would create it with mode 0600, and ``os.replace``
    keeps the temporary's mode, so every written image would end up private to
    its owner. Opening with mode 0666 lets the process umask decide, exactly as
    for a file created by ``open(path, "w")``.
    """
    for _ in range(100):
        candidate = directory / _temp_name(name, suffix)
        try:
            fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise InputError(f"cannot write in {directory}: {exc.strerror or exc}") from None
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


def output_target(path: str | os.PathLike, what: str = "output", create_dirs: bool = True) -> Path:
    """The file an output named ``path`` replaces, checked by the output policy.

    A symbolic link (a chain of them, a dangling one too) is followed: the
    returned path is the file it names, which is written (a temporary file
    beside it, renamed over it); the link itself stays. An existing target
    that is not a regular file (a directory, a device such as /dev/null, a
    FIFO, a socket) is refused, as is a path whose folder is a file.
    Missing folders are created with ``create_dirs`` (without it the path is
    only checked, so a command can check its outputs before any work). Raises
    :class:`~penumbra.errors.InputError` naming ``what`` and the path.
    """
    given = Path(path)
    if str(path) == "" or given.name in ("", ".", ".."):
        raise InputError(f"{what} {str(path)!r} is not a file name")
    target = Path(os.path.realpath(given)) if given.is_symlink() else given
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise InputError(f"{what} {given}: a folder on its path is a file, not a folder") from None
    except OSError as exc:
        raise InputError(f"{what} {given}: {exc.strerror or exc}") from None
    if st is not None and not stat.S_ISREG(st.st_mode):
        kind = ("a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode)
                else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        via = f" (through the link {given})" if target != given else ""
        raise InputError(f"{what} {target}{via} is {kind}: penumbra replaces only regular files")
    directory = target.parent
    if not directory.is_dir():
        existing = next((p for p in directory.parents if p.exists()), None)
        if directory.exists() or (existing is not None and not existing.is_dir()):
            raise InputError(f"{what} {given}: a folder on its path is a file, not a folder")
        if create_dirs:
            try:
                directory.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise InputError(f"{what} {given}: cannot create the folder {directory}: "
                                 f"{exc.strerror or exc}") from None
    return target


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (True when that cannot be told: its age decides then)."""
    if pid <= 0 or os.name != "posix":   # on Windows os.kill(pid, 0) would terminate the process
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError as exc:          # EPERM: someone else's live process
        return exc.errno != errno.ESRCH
    return True


def remove_stale_temporaries(path: str | os.PathLike, now: float | None = None) -> list[Path]:
    """Remove temporary files of earlier writes to ``path`` that were left behind.

    Ours are recognised by name: ``.<name>.tmp-<pid>-<hex>[suffix]`` (Python's
    atomic writes), ``<name>.tmp-<pid>-<counter>`` (the library's bake
    checkpoints, capi/src/io/fiv_file.c) and ``.<name>.<hex>.tmp[suffix]``
    (older versions, no pid). One is removed when its process (on this host)
    is gone and it was not modified for STALE_GRACE_SECONDS, or when it was
    not modified for STALE_AGE_SECONDS. Returns the removed files; files that
    cannot be removed are left alone.
    """
    target = Path(path)
    directory, name = target.parent, target.name
    n = re.escape(name)
    patterns = (re.compile(rf"^\.{n}\.tmp-(\d+)-[0-9a-f]{{12}}.*$"), re.compile(rf"^{n}\.tmp-(\d+)-\d+$"),
                re.compile(rf"^\.{n}\.[0-9a-f]{{12}}\.tmp.*$"))
    now = time.time() if now is None else now
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        match = next((m for m in (p.match(entry.name) for p in patterns) if m), None)
        if match is None:
            continue
        try:
            st = entry.stat(follow_symlinks=False)
        except OSError:
            continue
        if not stat.S_ISREG(st.st_mode):
            continue
        age = now - st.st_mtime
        pid = int(match.group(1)) if match.groups() else 0
        dead = match.groups() and pid != os.getpid() and not _pid_alive(pid)
        if age >= STALE_AGE_SECONDS or (dead and age >= STALE_GRACE_SECONDS):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed.append(Path(entry.path))
    return removed


class _Staged:
    """The writes of one :func:`all_or_nothing` block: (temporary, target) pairs."""

    def __init__(self) -> None:
        self.pending: list[tuple[Path, Path]] = []


_STAGE: contextvars.ContextVar[_Staged | None] = contextvars.ContextVar("penumbra_output_stage", default=None)


@contextlib.contextmanager
def all_or_nothing() -> Iterator[None]:
    """Outputs written in the block appear together when it succeeds, or not at all.

    Each :func:`atomic_write` in the block writes its complete temporary file
    beside its target but does not rename it; when the block ends without an
    exception, every temporary file is renamed over its target, one after the
    other (each rename is atomic; they are not one transaction, but nothing
    is left that can fail but a rename). When the block raises (including
    ``KeyboardInterrupt``), the temporary files are removed and no target is
    touched. Two writes to the same target in one block are refused.
    """
    outer = _STAGE.get()
    if outer is not None:   # nested: the outermost block decides
        yield
        return
    stage = _Staged()
    token = _STAGE.set(stage)
    try:
        yield
    except BaseException:
        for tmp, _ in stage.pending:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        raise
    finally:
        _STAGE.reset(token)
    for i, (tmp, target) in enumerate(stage.pending):
        try:
            os.replace(tmp, target)
        except BaseException:
            for rest, _ in stage.pending[i:]:
                with contextlib.suppress(OSError):
                    os.unlink(rest)
            raise


def atomic_write(path: str | os.PathLike, write_fn: Callable[[str], object], suffix: str | None = None) -> Path:
    """Write ``path`` atomically through a temporary file in the same directory.

    ``write_fn(tmp_path)`` must write the complete file at ``tmp_path`` (a
    ``str``; it exists and is empty when ``write_fn`` is called). This suits
    libraries that only accept a file name. When ``write_fn`` returns, the
    temporary file is flushed to disk and moved over ``path`` with
    ``os.replace``, which is atomic within one file system, so readers see
    either the old file or the complete new one. Inside :func:`all_or_nothing`
    the move waits for the end of the block.

    ``path`` goes through :func:`output_target` first: a symbolic link is
    followed (the file it names is replaced), and a target that is not a
    regular file, or a path under a file, is an InputError. Missing parent
    directories are created. Stale temporary files of earlier writes to the
    target are removed (:func:`remove_stale_temporaries`).

    If ``write_fn`` raises (including ``KeyboardInterrupt``), the temporary file
    is removed, any existing file at ``path`` is left untouched, and the
    exception propagates.

    ``suffix`` is the temporary file's extension; by default it is ``path``'s
    own suffix, because some writers pick the file format from the extension.

    Returns ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    target = output_target(path)
    stage = _STAGE.get()
    if stage is not None and any(os.path.abspath(t) == os.path.abspath(target) for _, t in stage.pending):
        raise InputError(f"{path} is named as more than one output")
    remove_stale_temporaries(target)
    tmp = _create_temp_file(target.parent, target.name, target.suffix if suffix is None else suffix)
    try:
        write_fn(str(tmp))
        _fsync_file(tmp)
        if stage is not None:
            stage.pending.append((tmp, target))
        else:
            os.replace(tmp, target)
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
