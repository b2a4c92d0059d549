"""Fan work out as dask.distributed tasks: one way for the data set generator, the grid search and
the validation sweep.

`open_client(scheduler, workers)` opens a Client on a LocalCluster of `workers` single-threaded
worker processes (default: all cores), or on a running scheduler given as tcp://host:port (the
`--scheduler` option of `slip dataset`, `slip train` and `slip reproduce validation`), and closes
both cleanly. `as_done(client, fn, jobs)` submits fn(*job) per job and yields (index, result) as
tasks finish, with a tqdm bar; `map_tasks` returns the results in job order. Every caller seeds a
task by its index or point, never by the worker that runs it, so results do not depend on the
worker count. Workers import this package, so a remote cluster needs it installed (the same version).
"""
from __future__ import annotations

import os
import uuid
from contextlib import contextmanager
from typing import Callable, Iterator, Sequence
from urllib.parse import urlsplit

from incipient_slip.errors import UsageError

CONNECT_TIMEOUT_S = 10.0          # how long to try a --scheduler address before giving up


def check_scheduler(address: str | None) -> str | None:
    """Return `address` if it reads tcp://host:port (or tls://; inproc:// is an in-process
    cluster's, as tests use), else raise UsageError."""
    if address is None:
        return None
    try:
        parts = urlsplit(str(address))
        ok = (parts.scheme in ("tcp", "tls") and parts.hostname and parts.port and not parts.path.strip("/")) \
            or (parts.scheme == "inproc" and parts.netloc)
    except ValueError:                          # a port that is not a number
        ok = False
    if not ok:
        raise UsageError(f"--scheduler {address!r}: expected tcp://host:port")
    return str(address)


def check_workers(workers: int | None) -> int:
    """Return the worker count (default: all cores); raise UsageError below 1."""
    if workers is not None and workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
    return int(workers or os.cpu_count() or 1)


@contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None):
    """Yield a dask Client on `scheduler` (tcp://host:port) or on a LocalCluster of `workers`
    single-threaded processes; close it (and the cluster) on exit."""
    import dask
    from dask.distributed import Client, LocalCluster

    scheduler = check_scheduler(scheduler)
    n = check_workers(workers)
    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except OSError as exc:
            raise UsageError(f"--scheduler {scheduler}: no dask scheduler answered within "
                             f"{CONNECT_TIMEOUT_S:g} s ({exc.__class__.__name__})") from None
    else:
        # the workers' sampling profiler costs ~10 % CPU on our short tasks (docs/performance.md)
        with dask.config.set({"distributed.worker.profile.enabled": False}):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0")
        client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def as_done(client, fn: Callable, jobs: Sequence[tuple], *, desc: str, progress: bool = True,
            key: str = "task", leave: bool = True) -> Iterator[tuple[int, object]]:
    """Submit fn(*job) for every job; yield (index, result) in completion order with a progress bar.
    A task's error is raised here; leaving early cancels the tasks not yet done."""
    from dask.distributed import as_completed
    from tqdm import tqdm

    run = uuid.uuid4().hex[:8]                  # keys unique per call: two calls never share a task
    futures = [client.submit(fn, *job, key=f"{key}-{run}-{i}", pure=False) for i, job in enumerate(jobs)]
    index = {f.key: i for i, f in enumerate(futures)}
    try:
        with tqdm(total=len(futures), desc=desc, unit="task", disable=not progress, leave=leave) as bar:
            for fut in as_completed(futures):
                res = fut.result()
                bar.update()
                yield index[fut.key], res
    finally:
        client.cancel([f for f in futures if not f.done()])


def map_tasks(client, fn: Callable, jobs: Sequence[tuple], **kw) -> list:
    """Return [fn(*job) for job in jobs], run as tasks on `client` (see as_done)."""
    out: list = [None] * len(jobs)
    for i, res in as_done(client, fn, jobs, **kw):
        out[i] = res
    return out
