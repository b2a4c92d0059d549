"""Where the repository's data directories are: launch files, scenes and shipped models; where a
run's output file goes (`prepare_output`: its folder created, writable); and how an output file is
written (`written_atomically`: whole or not at all, never a partial file left on a full disk).

The project is installed editable, so the repository root is two levels above this package.
"""
from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path


def repo_root() -> Path:
    """Return the repository root (the directory holding pyproject.toml)."""
    return Path(__file__).resolve().parents[2]


def launch_dir() -> Path:
    """Return the directory of launch YAML files."""
    return repo_root() / "launch"


def scenes_dir() -> Path:
    """Return the directory of simulator scene YAML files."""
    return repo_root() / "scenes"


def model_dir() -> Path:
    """Return the directory of shipped model files."""
    return repo_root() / "models"


def runs_dir() -> Path:
    """Return runs/ at the repository root (git-ignored outputs of runs, training and studies)."""
    return repo_root() / "runs"


def docs_dir() -> Path:
    """Return docs/ at the repository root (the hand-written pages the experiments write into)."""
    return repo_root() / "docs"


def prepare_output(path: str | Path) -> Path:
    """Makes an output file writable where it goes: creates its folder (as the run summary always
    did) and writes and removes a probe file there. OSError otherwise (a folder that cannot be
    created or written, a directory at `path`); `output_error` words it in one line."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "is a directory", str(path))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:     # a file where a folder of the path should be
        blocker = next(p for p in reversed(path.parents) if p.exists() and not p.is_dir())
        raise NotADirectoryError(errno.ENOTDIR, "a file, not a folder", str(blocker)) from None
    fd, probe = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".probe", dir=path.parent)
    os.close(fd)
    os.unlink(probe)
    if path.exists() and not os.access(path, os.W_OK):
        raise PermissionError(errno.EACCES, "not writable", str(path))
    return path


def output_error(exc: OSError) -> str:
    """An OSError of an output path in one line: 'No such file or directory: /proc/nope'."""
    reason = exc.strerror or str(exc)
    return f"{reason}: {exc.filename}" if exc.filename else reason


@contextlib.contextmanager
def written_atomically(path: str | Path) -> Iterator[Path]:
    """Yields a temporary path beside `path` to write; when the block ends, it replaces `path`, so a
    reader sees the old file or the whole new one. On any error (a full disk: ENOSPC) the temporary
    file is removed, so a failed write leaves no partial file to fill the disk or be read. The
    temporary name is hidden and keeps the suffix (np.savez appends .npz to a name without it)."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def out_of_space(exc: BaseException) -> bool:
    """True for the OSError of a full disk or an exhausted quota."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
