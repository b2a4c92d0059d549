"""A content-hashed cache of deterministic results on disk, so reruns never compute them twice.

An entry's key is a SHA-256 over everything its result depends on (the data's bytes, the
parameters, the library and code versions the caller names), so a change of any of them is a
different key: nothing is ever invalidated, a stale entry is simply never asked for again. So the
cache is bounded: at the end of each `use` block the least recently used entries (a hit renews an
entry) are removed until it holds at most SLIP_CACHE_MAX_GB (default 8; one full `slip reproduce
all --joint` stored about 4 GB). A result that cannot be stored (a full disk) is used all the same,
with one warning: the cache only saves time, it never fails a run.
The cache is on only where a directory is given, by `use(directory)` around a run (`slip reproduce`
uses runs/cache, and WORK/cache on the quick budget) or SLIP_CACHE_DIR in the environment; code
that runs without one (tests, library calls) computes everything. `rm -rf runs/cache` empties it.
"""
from __future__ import annotations

import hashlib
import json
import os
import pickle
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, TypeVar

import numpy as np

from .errors import UsageError
from .paths import output_error, written_atomically

T = TypeVar("T")
ENV = "SLIP_CACHE_DIR"
MAX_GB_ENV = "SLIP_CACHE_MAX_GB"
DEFAULT_MAX_GB = 8.0
_unstored: set[str] = set()      # kinds whose failed store was reported (one warning each)


def root() -> Path | None:
    """Return the cache directory in use, or None (cache off)."""
    value = os.environ.get(ENV, "")
    return Path(value) if value else None


@contextmanager
def _setting(directory: str | None):
    """Set the cache's environment variable to `directory` (None: unset it) for the block, and
    for the processes started in it (they inherit the environment); restore it afterwards."""
    old = os.environ.pop(ENV, None)
    if directory is not None:
        os.environ[ENV] = directory
    try:
        yield
    finally:
        os.environ.pop(ENV, None)
        if old is not None:
            os.environ[ENV] = old


@contextmanager
def use(directory: Path | None):
    """Turn the cache on at `directory` (None: leave as it is) for the block, and for the processes
    started in it (the environment is inherited); restore the previous setting afterwards."""
    if directory is None:
        yield
        return
    limit = max_bytes()         # a bad limit is refused before the run, not after it
    try:
        with _setting(str(directory)):
            yield
    finally:
        removed, freed = prune(Path(directory), limit)
        if removed:
            print(f"cache: removed the {removed} least recently used entries ({freed / 1e9:.2f} GB) of "
                  f"{directory}, to keep it under {limit / 1e9:g} GB ({MAX_GB_ENV})", file=sys.stderr)


def max_bytes() -> int:
    """The cache's size limit: SLIP_CACHE_MAX_GB (a number of GB, >= 0), else DEFAULT_MAX_GB."""
    text = os.environ.get(MAX_GB_ENV, "")
    try:
        gb = float(text) if text else DEFAULT_MAX_GB
    except ValueError:
        gb = -1.0
    if not gb >= 0:         # NaN too
        raise UsageError(f"{MAX_GB_ENV}={text!r}: give the cache's size limit in GB, a number >= 0")
    return int(gb * 1e9)


def prune(directory: Path, limit: int) -> tuple[int, int]:
    """Removes the least recently used entries of the cache at `directory` (oldest modification
    time first: a hit renews it) until it holds at most `limit` bytes; the hidden temporary file a
    killed writer left counts as an entry. Another run's store that loses its file to this only
    warns (`cached`). Returns (entries removed, bytes freed)."""
    entries = []
    for path in directory.glob("*/*/*.pkl"):
        try:
            st = path.stat()
        except OSError:
            continue
        entries.append((st.st_mtime, st.st_size, path))
    total = sum(size for _, size, _ in entries)
    removed = freed = 0
    for _, size, path in sorted(entries):
        if total <= limit:
            break
        try:
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            continue
        total -= size
        removed, freed = removed + 1, freed + size
    return removed, freed


def off():
    """Turn the cache off for the block (and the processes started in it); also a decorator. For
    work whose time is the result being measured, which a cached entry would report as taking none."""
    return _setting(None)


def digest(*parts: Any) -> str:
    """Return the SHA-256 hex digest of `parts` (arrays by dtype, shape and bytes; dicts by sorted
    keys; lists and tuples item by item; anything else by its JSON or repr)."""
    h = hashlib.sha256()

    def add(x):
        if isinstance(x, np.ndarray):
            a = np.ascontiguousarray(x)
            h.update(f"nd{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        elif isinstance(x, dict):
            h.update(b"{")
            for k in sorted(x, key=str):
                add(str(k))
                add(x[k])
            h.update(b"}")
        elif isinstance(x, (list, tuple)):
            h.update(b"[")
            for v in x:
                add(v)
            h.update(b"]")
        else:
            h.update(json.dumps(x, default=repr).encode() if isinstance(x, (str, int, float, bool, type(None)))
                     else repr(x).encode())
            h.update(b";")
    for p in parts:
        add(p)
    return h.hexdigest()


def source_version(*paths: Path) -> str:
    """Return a short hash of source files (each path a file or a directory of *.py files)."""
    h = hashlib.sha256()
    for path in paths:
        files = sorted(Path(path).glob("*.py")) if Path(path).is_dir() else [Path(path)]
        for f in files:
            h.update(f.name.encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def cached(kind: str, key: str, compute: Callable[[], T]) -> T:
    """Return the stored result of `kind`/`key`, or compute, store and return it (cache off: compute)."""
    base = root()
    if base is None:
        return compute()
    path = base / kind / key[:2] / f"{key}.pkl"
    try:
        with open(path, "rb") as f:
            value = pickle.load(f)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
        pass
    else:
        try:
            os.utime(path)          # used now: the last to go when the cache is pruned
        except OSError:
            pass
        return value
    value = compute()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with written_atomically(path) as tmp, open(tmp, "wb") as f:
            pickle.dump(value, f, protocol=pickle.HIGHEST_PROTOCOL)
    except OSError as exc:
        if kind not in _unstored:
            _unstored.add(kind)
            print(f"cache: a {kind} result was not stored ({output_error(exc)}); it is used all the same, "
                  "only computed again next time", file=sys.stderr)
    return value
