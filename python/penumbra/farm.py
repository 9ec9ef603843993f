"""Work spread over a dask.distributed cluster (docs/farm.md): a client of a
running scheduler (``scheduler="tcp://host:8786"``) or of a LocalCluster of
``workers`` processes started here, and a penumbra context per worker thread.

dask is optional: penumbra imports without it, and asking for a cluster
without it installed raises InputError with the pip command before any work
starts. The work functions themselves are plain top-level functions of
penumbra modules (e.g. penumbra.methods.fiv.bake_to_cache), so a worker needs
penumbra importable and the input files at the same paths (a shared file
system), nothing else.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator

from .errors import InputError, PenumbraError

PIP_COMMAND = 'pip install "dask[distributed]"'

__all__ = ["PIP_COMMAND", "client", "require_dask", "run", "worker_context", "worker_name"]


def require_dask():
    """The ``distributed`` module, or InputError naming the pip command that installs it."""
    try:
        import distributed
    except ImportError:
        raise InputError(f"running on a Dask cluster needs dask.distributed, which is not installed: "
                         f"{PIP_COMMAND}") from None
    return distributed


@contextmanager
def client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A dask.distributed Client: of the scheduler at ``scheduler``, else of a
    LocalCluster of ``workers`` single-threaded worker processes (closed on
    exit). A LocalCluster's nannies restart a worker that dies, and the
    scheduler gives its unfinished tasks to the others."""
    distributed = require_dask()
    if scheduler is None and (workers is None or workers < 1):
        raise InputError(f"a local Dask cluster needs at least 1 worker, not {workers}")
    cluster = None
    try:
        if scheduler is not None:
            c = distributed.Client(scheduler)
        else:
            # One thread per process: a penumbra context is used by one thread
            # at a time, and each bake keeps its OpenCL device busy by itself.
            cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                               dashboard_address=None, silence_logs=logging.ERROR)
            c = distributed.Client(cluster)
    except OSError as exc:
        if cluster is not None:
            cluster.close()
        raise InputError(f"cannot reach the Dask scheduler {scheduler or '(local cluster)'}: {exc}") from None
    try:
        yield c
    finally:
        c.close()
        if cluster is not None:
            cluster.close()


_local = threading.local()


def worker_context(device: str | None = None):
    """This thread's penumbra Context, created on first use: every worker
    process (and thread) gets an OpenCL context of its own."""
    from .core import Context

    ctx = getattr(_local, "contexts", {}).get(device)
    if ctx is None:
        ctx = Context(device)
        _local.contexts = {**getattr(_local, "contexts", {}), device: ctx}
    return ctx


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def run(c, fn: Callable[[Any], dict], items: Iterable[Any], log: Callable[[str], None] | None = None,
        describe: Callable[[dict], str] = str, no_workers_s: float = 120.0) -> list[dict]:
    """``fn(item)`` for every item on the cluster of client ``c``; the results
    in item order. Tasks of a worker that dies are run again elsewhere (the
    work functions resume from their files); a task that raises stops the
    run with that error, and so does a cluster left without any worker for
    ``no_workers_s`` seconds (workers that cannot start, or all lost) instead
    of waiting for ever. ``log`` gets one line per finished task."""
    distributed = require_dask()
    items = list(items)
    start = time.perf_counter()
    futures = c.map(fn, items, pure=False)
    index = {f.key: i for i, f in enumerate(futures)}
    results: list[dict | None] = [None] * len(items)
    pending, finished, workerless_since = set(futures), 0, None
    while pending:
        try:
            done, pending = distributed.wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
        except TimeoutError:
            done = set()
        for future in done:
            results[index[future.key]] = r = future.result()
            finished += 1
            if log:
                log(f"[{finished}/{len(items)}, {time.perf_counter() - start:.1f} s] {describe(r)}")
        if done or c.nthreads():
            workerless_since = None
        elif workerless_since is None:
            workerless_since = time.monotonic()
        elif time.monotonic() - workerless_since > no_workers_s:
            raise PenumbraError(f"the Dask cluster has had no workers for {no_workers_s:g} s with {len(pending)} of "
                                f"{len(items)} jobs left (workers that cannot start or were all lost: see the "
                                "workers' logs); finished results are in their files")
    return results  # type: ignore[return-value]
