"""Discovery: where a graph lives and which nodes are in it, with no endpoint lists anywhere.

Each node binds one XPUB socket (ipc by default) and announces itself by writing a small JSON
file `<graph dir>/<name>-<pid>.<instance>.node.json` (instance: random, so that two nodes of one
name and pid number in different PID namespaces, each PID 1 of its container, never share a
file or an ipc socket) holding its endpoint and the topics it publishes and
subscribes. A node's single SUB socket connects to every announced endpoint, rescanning the
directory when it changes. So there is no broker hop (a message goes publisher -> subscriber
directly, the same path as raw pyzmq) and no list of endpoints in any launch file. See
docs/graph.md for why and for the measured cost.

The graph directory is, in order: `$SLIP_GRAPH_DIR`; else `<base>/<graph>` with graph =
`$SLIP_GRAPH` or "default" and base = `$XDG_RUNTIME_DIR/incipient-slip` when that exists, else
`/tmp/incipient-slip-<uid>`. A node started by hand and `slip topic echo` in another shell find
a launched graph because they all default to the same directory.

Trust: like ssh with its keys, a graph directory (and the base directory above it) that is not
owned by the current user, or that group or others may write, is refused (`GraphDirError`, one
line saying how to fix it); so are announcement files not owned by the current user or writable
by others (skipped, counted in `Discovery.refused`). Another local user who created the
directory first could otherwise announce a publisher that our nodes subscribe to.
"""
from __future__ import annotations

import json
import os
import re
import secrets
import socket
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["graph_dir", "GraphNameError", "GraphDirError", "check_graph_dir", "NodeInfo", "announce", "withdraw", "scan", "remove_pid",
           "ipc_endpoint", "Discovery", "GRAPH_DIR_ENV", "GRAPH_ENV", "TRANSPORT_ENV"]

GRAPH_DIR_ENV = "SLIP_GRAPH_DIR"
GRAPH_ENV = "SLIP_GRAPH"
TRANSPORT_ENV = "SLIP_TRANSPORT"     # "ipc" (default), "tcp" (CURVE) or "tcp-insecure" (security.py)
SUFFIX = ".node.json"
_PROBE_TIMEOUT_S = 0.2              # a loopback tcp probe that takes longer proves nothing
_ORPHAN_SOCKET_S = 10.0             # an ipc socket with no announcement younger than this is kept
_MAX_IPC_PATH = 100                  # sun_path is 108 bytes including the NUL; keep a margin
_SAFE = re.compile(r"[^A-Za-z0-9_.-]")
_PID_FILE = re.compile(r"^\.?(?:.*-)?(\d+)(?:\.[0-9a-f]+)?(?:\.node\.json(?:\.tmp)?|\.sock)$")   # what a node leaves


class GraphNameError(ValueError):
    """A graph name (--graph, $SLIP_GRAPH) that cannot be a directory name."""


class GraphDirError(GraphNameError):
    """A graph directory this user must not trust: owned by someone else, or writable by others.
    (A GraphNameError, so every command that reports a bad graph name reports it the same way.)"""


def _unsafe(st: os.stat_result) -> str:
    """Why a file or directory with this stat must not be trusted ("" if it can be)."""
    if st.st_uid != os.getuid():
        return f"owned by uid {st.st_uid}, not by you (uid {os.getuid()})"
    if st.st_mode & 0o022:
        who = " and ".join(w for bit, w in ((0o020, "group"), (0o002, "others")) if st.st_mode & bit)
        return f"writable by {who} (mode {st.st_mode & 0o777:o})"
    return ""


def check_graph_dir(path: Path) -> Path:
    """`path` if it is a directory only the current user can write; GraphDirError otherwise."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise GraphDirError(f"graph directory {path}: {exc.strerror}") from None
    why = _unsafe(st)
    if why:
        fix = (f"remove it (another user may have created it) or set {GRAPH_DIR_ENV} to a directory of "
               f"your own" if st.st_uid != os.getuid() else f"chmod go-w {path}")
        raise GraphDirError(f"graph directory {path} is {why}; refusing to use it: {fix}")
    return path


def graph_dir(graph: str | None = None, create: bool = True) -> Path:
    """The directory of the graph named `graph` (or of $SLIP_GRAPH_DIR / $SLIP_GRAPH / default)."""
    explicit = os.environ.get(GRAPH_DIR_ENV)
    if explicit and graph is None:
        path = Path(explicit)
    else:
        name = graph or os.environ.get(GRAPH_ENV) or "default"
        if _SAFE.search(name) or name in (".", ".."):
            origin = "--graph" if graph else f"${GRAPH_ENV}"
            raise GraphNameError(f"graph name {name!r} ({origin}): use letters, digits, '_', '.', '-'")
        runtime = os.environ.get("XDG_RUNTIME_DIR")
        if runtime and os.path.isdir(runtime) and os.access(runtime, os.W_OK):
            base = Path(runtime) / "incipient-slip"
        else:
            base = Path(tempfile.gettempdir()) / f"incipient-slip-{os.getuid()}"
        path = base / name
        if create:
            base.mkdir(parents=True, exist_ok=True, mode=0o700)
        if base.exists():
            check_graph_dir(base)
    if create:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
    return check_graph_dir(path) if path.exists() else path


def safe_name(name: str) -> str:
    """`name` with every character a file name should not hold replaced by '_'."""
    return _SAFE.sub("_", name.strip("/")) or "node"


def new_instance() -> str:
    """A node's instance id: random, in its file and socket names beside name and pid."""
    return secrets.token_hex(4)


def _stem(name: str, pid: int, instance: str) -> str:
    return f"{safe_name(name)}-{pid}" + (f".{instance}" if instance else "")


def ipc_endpoint(directory: Path, name: str, pid: int, instance: str = "") -> str:
    """The ipc endpoint of a node's XPUB; ValueError if the path is too long for a socket."""
    path = f"{directory}/{_stem(name, pid, instance)}.sock"
    if len(path.encode()) > _MAX_IPC_PATH:
        path = f"{directory}/{instance or pid}.sock"     # the instance alone is unique too
    if len(path.encode()) > _MAX_IPC_PATH:
        raise ValueError(f"ipc socket path {path!r} is longer than {_MAX_IPC_PATH} bytes; set "
                         f"{GRAPH_DIR_ENV} to a shorter directory")
    return "ipc://" + path


# A node's INPUTS/OUTPUTS key (and announced topic) for "every topic": the recorder reads all,
# replay writes what its file holds. The launcher counts such a node as a reader (writer) of
# every topic of the launch.
ANY_TOPIC = "*"
# The type an every-topic reader announces once it receives only the topics it asks for at the
# time (`Node.receive_only`): it connects to every publisher but may not be subscribed to a topic.
ON_DEMAND = "on demand"


@dataclass
class NodeInfo:
    """One announced node: name, pid, endpoint, {topic: type name} published and subscribed,
    and its parameters as resolved at its start (`slip param`; read-only: nothing reads them back)."""

    name: str
    pid: int
    endpoint: str
    publishes: dict[str, str] = field(default_factory=dict)
    subscribes: dict[str, str] = field(default_factory=dict)
    started_ns: int = 0
    path: Path | None = None
    pidns: str = ""       # the PID namespace its pid is in ("pid:[4026531836]"); "" unknown
    netns: str = ""       # the network namespace its tcp endpoint is in; "" unknown
    params: dict[str, Any] = field(default_factory=dict)
    instance: str = ""    # random id in its file names (`new_instance`); "" for a hand-written one
    identity: str = ""    # the keystore identity whose key it holds over tcp (security.py); "": its name


def announce(directory: Path, info: NodeInfo) -> Path:
    """Write (atomically) the announcement file of a node; returns its path."""
    path = directory / f"{_stem(info.name, info.pid, info.instance)}{SUFFIX}"
    tmp = directory / f".{path.name}.tmp"
    tmp.write_text(json.dumps({"name": info.name, "pid": info.pid, "endpoint": info.endpoint,
                               "publishes": info.publishes, "subscribes": info.subscribes,
                               "started_ns": info.started_ns, "pidns": info.pidns,
                               "netns": info.netns, "params": info.params,
                               "instance": info.instance, "identity": info.identity}, default=str))
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


def namespace(kind: str) -> str:
    """This process's namespace of `kind` ("pid", "net"), e.g. "pid:[4026531836]"; "" if unknown."""
    try:
        return os.readlink(f"/proc/self/ns/{kind}")
    except OSError:
        return ""


def _alive(pid: int, started_ns: int = 0) -> bool:
    """True if process `pid` of OUR pid namespace exists and (when known) is not younger than
    `started_ns`, the wall time (time.time_ns) its node announced itself: a pid reused by a newer
    process is not that node. A started_ns before the machine booted is no wall time (a client
    that wrote a monotonic value): it is not used."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    boot_ns = _boot_time_ns()
    if started_ns and boot_ns is not None and started_ns > boot_ns:
        born_ns = _start_time_ns(pid, boot_ns)
        # 10 s of slack: boot-time arithmetic rounds to clock ticks, and a wall clock stepped
        # back must not make a live node look dead (its files would be removed under it)
        if born_ns is not None and born_ns > started_ns + 10_000_000_000:
            return False
    return True


def _boot_time_ns() -> int | None:
    try:
        for line in Path("/proc/stat").read_text().splitlines():
            if line.startswith("btime "):
                return int(line.split()[1]) * 1_000_000_000
    except (OSError, ValueError):
        pass
    return None


def _start_time_ns(pid: int, boot_ns: int) -> int | None:
    """Wall time process `pid` started (Linux /proc), or None where that is not known."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        ticks = int(stat.rsplit(")", 1)[1].split()[19])      # field 22, starttime
        return boot_ns + ticks * 1_000_000_000 // os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _refuses(endpoint: str, netns: str = "") -> bool:
    """True only if the endpoint provably has no listener: a connection to its ipc socket (or to
    its loopback tcp port, when announced from our network namespace) is refused, or the ipc
    socket file is gone. A probe that is accepted, times out or cannot be made proves nothing."""
    if endpoint.startswith("ipc://"):
        family, address = socket.AF_UNIX, endpoint[6:]
    elif endpoint.startswith("tcp://127.0.0.1:") and netns and netns == namespace("net"):
        family, address = socket.AF_INET, ("127.0.0.1", int(endpoint.rsplit(":", 1)[1]))
    else:
        return False
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.settimeout(_PROBE_TIMEOUT_S)
        try:
            probe.connect(address)
        except (ConnectionRefusedError, FileNotFoundError):
            return True
        except OSError:
            return False
    return False


def _older_than(entry: os.DirEntry, seconds: float) -> bool:
    try:
        return entry.stat(follow_symlinks=False).st_mtime < time.time() - seconds
    except OSError:
        return False


def is_dead(info: NodeInfo) -> bool:
    """True only when the node of an announcement is proven gone: its pid is dead (or reused)
    in our own pid namespace, or, for a node in another or an unknown pid namespace (a
    container), its endpoint refuses connections. What cannot be proven dead is alive."""
    if info.pidns and info.pidns == namespace("pid"):
        return not _alive(info.pid, info.started_ns)
    return _refuses(info.endpoint, info.netns)


def remove_pid(directory: Path, pid: int, pidns: str | None = None) -> int:
    """Removes what a node of process `pid` of PID namespace `pidns` (default: ours) left in a
    graph directory (announcement, ipc socket, half-written file), e.g. after it was SIGKILLed;
    returns how many files. The same number in another PID namespace is another process: its
    files are removed only when its socket proves nothing listens (`_refuses`)."""
    pidns = namespace("pid") if pidns is None else pidns
    try:
        entries = [e for e in os.scandir(directory)
                   if (m := _PID_FILE.match(e.name)) and int(m.group(1)) == pid]
    except FileNotFoundError:
        return 0
    stems = {}       # stem -> True if that stem's process is the one meant (or proven gone)
    for entry in entries:
        if entry.name.endswith(SUFFIX) and not entry.name.startswith("."):
            try:
                raw = json.loads(Path(entry.path).read_text())
                theirs, endpoint = str(raw.get("pidns", "")), str(raw["endpoint"])
            except (OSError, ValueError, KeyError, TypeError):
                continue
            stems[entry.name[:-len(SUFFIX)]] = (theirs == pidns) or _refuses(endpoint, str(raw.get("netns", "")))
    removed = 0
    for entry in entries:
        stem = entry.name.lstrip(".").split(".node.json")[0].removesuffix(".sock")
        ours = stems.get(stem)
        if ours is None:     # no announcement: a socket (or a half-written file) of a node
            sock = directory / f"{stem}.sock"    # killed before it announced, if nothing listens
            ours = not sock.exists() or _refuses("ipc://" + str(sock))
        if ours:
            try:
                os.unlink(entry.path)
                removed += 1
            except OSError:
                pass
    return removed


def scan(directory: Path, clean: bool = True, refused: dict[str, str] | None = None,
         log=None) -> list[NodeInfo]:
    """The nodes announced in a graph directory; with `clean`, the files of nodes proven dead
    (`is_dead`; ipc sockets with no announcement: nothing listens) are removed, each with one
    line to `log` (default: stderr). Announcements this user must not trust (see
    `check_graph_dir`) are skipped, and put in `refused` ({file name: why})."""
    log = log or _stderr
    out = []
    try:
        entries = list(os.scandir(directory))
    except FileNotFoundError:
        return out
    names = {e.name for e in entries}
    for entry in entries:
        if not entry.name.endswith(SUFFIX) or entry.name.startswith("."):
            # a socket is bound before its announcement is written, and between bind() and
            # listen() it refuses connections (a window a loaded machine widens): one with no
            # announcement is removed only when it is older than that and nothing listens on it
            if clean and entry.name.endswith(".sock") and not any(
                    n.endswith(SUFFIX) and n[:-len(SUFFIX)] == entry.name[:-5] for n in names) \
                    and _older_than(entry, _ORPHAN_SOCKET_S) and _refuses("ipc://" + entry.path):
                try:
                    os.unlink(entry.path)
                except OSError:
                    pass
            continue
        try:
            why = _unsafe(entry.stat(follow_symlinks=False))
            if why or entry.is_symlink():
                if refused is not None:
                    refused[entry.name] = why or "a symbolic link"
                continue
            raw = json.loads(Path(entry.path).read_text())
            info = NodeInfo(str(raw["name"]), int(raw["pid"]), str(raw["endpoint"]),
                            dict(raw.get("publishes", {})), dict(raw.get("subscribes", {})),
                            int(raw.get("started_ns", 0)), Path(entry.path),
                            str(raw.get("pidns", "")), str(raw.get("netns", "")),
                            dict(raw.get("params", {})), str(raw.get("instance", "")),
                            str(raw.get("identity", "")))
        except (OSError, ValueError, KeyError, TypeError):
            continue    # being replaced right now, or not ours
        if is_dead(info):
            if clean:
                log(f"removed the announcement of node {info.name} (pid {info.pid}, {entry.name}): "
                    f"its process is gone")
                withdraw(info)
            continue
        out.append(info)
    return out


def _stderr(text: str) -> None:
    print(f"[discovery] {text}", file=sys.stderr, flush=True)


class Discovery:
    """Tracks the endpoints announced in a graph directory, cheaply, for one SUB socket.

    `changes()` returns (endpoints to connect, endpoints to disconnect) since the last call. It
    rescans when the directory's mtime changes and in any case every `full_scan_s` (mtime has a
    coarse clock, so two changes in one tick could otherwise be missed).
    """

    def __init__(self, directory: Path, full_scan_s: float = 1.0, log=None):
        self.directory = directory
        self.full_scan_s = full_scan_s
        self.log = log or _stderr                  # one line per refused or removed announcement
        self.refused: dict[str, str] = {}          # announcement file -> why it is not trusted
        self.endpoints: set[str] = set()
        self.infos: list[NodeInfo] = []
        self._mtime = None
        self._last_full = 0.0

    def changes(self, accept=None) -> tuple[list[str], list[str]]:
        """(endpoints to connect, endpoints to disconnect) since the last call, of the announced
        nodes for which `accept(info)` is true (all when None; asked at every call, so a node
        whose announcement or whose reader's rule changed moves in or out at once)."""
        now = time.monotonic()
        try:
            mtime = os.stat(self.directory).st_mtime_ns
        except FileNotFoundError:
            mtime = None
        if mtime != self._mtime or now - self._last_full >= self.full_scan_s:
            self._mtime, self._last_full = mtime, now
            refused: dict[str, str] = {}
            self.infos = scan(self.directory, refused=refused, log=self.log)
            for name in refused.keys() - self.refused.keys():
                self.log(f"refused announcement {self.directory / name}: {refused[name]}")
            self.refused.update(refused)
        current = {info.endpoint for info in self.infos if accept is None or accept(info)}
        added, removed = sorted(current - self.endpoints), sorted(self.endpoints - current)
        self.endpoints = current
        return added, removed

    def info_of(self, endpoint: str) -> NodeInfo | None:
        """The announcement, as last scanned, of the node bound at `endpoint`."""
        for info in self.infos:
            if info.endpoint == endpoint:
                return info
        return None
