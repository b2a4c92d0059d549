"""Discovery: where a graph lives and which nodes are in it, with no endpoint lists anywhere.

Each node binds one XPUB socket (ipc by default) and announces itself by writing a small JSON
file `<graph dir>/<name>-<pid>.node.json` holding its endpoint and the topics it publishes and
subscribes. A node's single SUB socket connects to every announced endpoint, rescanning the
directory when it changes. So there is no broker hop (a message goes publisher -> subscriber
directly, the same path as raw pyzmq) and no list of endpoints in any launch file. See
docs/graph.md for why and for the measured cost.

The graph directory is, in order: `$SLIP_GRAPH_DIR`; else `<base>/<graph>` with graph =
`$SLIP_GRAPH` or "default" and base = `$XDG_RUNTIME_DIR/incipient-slip` when that exists, else
`/tmp/incipient-slip-<uid>`. A node started by hand and `slip topic echo` in another shell find
a launched graph because they all default to the same directory.
"""
from __future__ import annotations

import json
import os
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["graph_dir", "NodeInfo", "announce", "withdraw", "scan", "ipc_endpoint", "Discovery",
           "GRAPH_DIR_ENV", "GRAPH_ENV", "TRANSPORT_ENV"]

GRAPH_DIR_ENV = "SLIP_GRAPH_DIR"
GRAPH_ENV = "SLIP_GRAPH"
TRANSPORT_ENV = "SLIP_TRANSPORT"     # "ipc" (default) or "tcp" (127.0.0.1, random port)
SUFFIX = ".node.json"
_MAX_IPC_PATH = 100                  # sun_path is 108 bytes including the NUL; keep a margin
_SAFE = re.compile(r"[^A-Za-z0-9_.-]")


def graph_dir(graph: str | None = None, create: bool = True) -> Path:
    """The directory of the graph named `graph` (or of $SLIP_GRAPH_DIR / $SLIP_GRAPH / default)."""
    explicit = os.environ.get(GRAPH_DIR_ENV)
    if explicit and graph is None:
        path = Path(explicit)
    else:
        name = graph or os.environ.get(GRAPH_ENV) or "default"
        if _SAFE.search(name) or name in (".", ".."):
            raise ValueError(f"graph name {name!r}: use letters, digits, '_', '.', '-'")
        runtime = os.environ.get("XDG_RUNTIME_DIR")
        if runtime and os.path.isdir(runtime) and os.access(runtime, os.W_OK):
            base = Path(runtime) / "incipient-slip"
        else:
            base = Path(tempfile.gettempdir()) / f"incipient-slip-{os.getuid()}"
        path = base / name
    if create:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
    return path


def safe_name(name: str) -> str:
    """`name` with every character a file name should not hold replaced by '_'."""
    return _SAFE.sub("_", name.strip("/")) or "node"


def ipc_endpoint(directory: Path, name: str, pid: int) -> str:
    """The ipc endpoint of a node's XPUB; ValueError if the path is too long for a socket."""
    path = f"{directory}/{safe_name(name)}-{pid}.sock"
    if len(path.encode()) > _MAX_IPC_PATH:
        path = f"{directory}/{pid}.sock"
    if len(path.encode()) > _MAX_IPC_PATH:
        raise ValueError(f"ipc socket path {path!r} is longer than {_MAX_IPC_PATH} bytes; set "
                         f"{GRAPH_DIR_ENV} to a shorter directory")
    return "ipc://" + path


@dataclass
class NodeInfo:
    """One announced node: name, pid, endpoint, {topic: type name} published and subscribed."""

    name: str
    pid: int
    endpoint: str
    publishes: dict[str, str] = field(default_factory=dict)
    subscribes: dict[str, str] = field(default_factory=dict)
    started_ns: int = 0
    path: Path | None = None


def announce(directory: Path, info: NodeInfo) -> Path:
    """Write (atomically) the announcement file of a node; returns its path."""
    path = directory / f"{safe_name(info.name)}-{info.pid}{SUFFIX}"
    tmp = directory / f".{path.name}.tmp"
    tmp.write_text(json.dumps({"name": info.name, "pid": info.pid, "endpoint": info.endpoint,
                               "publishes": info.publishes, "subscribes": info.subscribes,
                               "started_ns": info.started_ns}))
    os.replace(tmp, path)
    info.path = path
    return path


def withdraw(info: NodeInfo) -> None:
    """Remove a node's announcement file and its ipc socket file."""
    for path in (info.path,
                 Path(info.endpoint[6:]) if info.endpoint.startswith("ipc://") else None):
        if path is not None:
            try:
                path.unlink()
            except OSError:
                pass


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def scan(directory: Path, clean: bool = True) -> list[NodeInfo]:
    """The nodes announced in a graph directory; files of dead processes are removed."""
    out = []
    try:
        entries = list(os.scandir(directory))
    except FileNotFoundError:
        return out
    for entry in entries:
        if not entry.name.endswith(SUFFIX) or entry.name.startswith("."):
            continue
        try:
            raw = json.loads(Path(entry.path).read_text())
            info = NodeInfo(str(raw["name"]), int(raw["pid"]), str(raw["endpoint"]),
                            dict(raw.get("publishes", {})), dict(raw.get("subscribes", {})),
                            int(raw.get("started_ns", 0)), Path(entry.path))
        except (OSError, ValueError, KeyError, TypeError):
            continue    # being replaced right now, or not ours
        if not _alive(info.pid):
            if clean:
                withdraw(info)
            continue
        out.append(info)
    return out


class Discovery:
    """Tracks the endpoints announced in a graph directory, cheaply, for one SUB socket.

    `changes()` returns (endpoints to connect, endpoints to disconnect) since the last call. It
    rescans when the directory's mtime changes and in any case every `full_scan_s` (mtime has a
    coarse clock, so two changes in one tick could otherwise be missed).
    """

    def __init__(self, directory: Path, full_scan_s: float = 1.0):
        self.directory = directory
        self.full_scan_s = full_scan_s
        self.endpoints: set[str] = set()
        self._mtime = None
        self._last_full = 0.0

    def changes(self) -> tuple[list[str], list[str]]:
        now = time.monotonic()
        try:
            mtime = os.stat(self.directory).st_mtime_ns
        except FileNotFoundError:
            mtime = None
        if mtime == self._mtime and now - self._last_full < self.full_scan_s:
            return [], []
        self._mtime, self._last_full = mtime, now
        current = {info.endpoint for info in scan(self.directory)}
        added, removed = sorted(current - self.endpoints), sorted(self.endpoints - current)
        self.endpoints = current
        return added, removed
