"""Transport security: a CURVE key pair per node and a permissions file, for a graph's TCP sockets.

`$SLIP_TRANSPORT` selects the transport: `ipc` (default: Unix sockets in the 0700 graph
directory, which only the user reaches), `tcp` (127.0.0.1, every socket CURVE-authenticated and
encrypted with per-node keys) or `tcp-insecure` (plain TCP, with a warning: every local user can
connect, read every topic and publish).

Over `tcp`, as SROS2 does it with an enclave per node and a permissions document:

* **A keystore**: `<graph dir>/keys/` (mode 0700), or the directory `$SLIP_KEYSTORE` names (a
  graph across hosts: copy it). Each identity has a pair in ZeroMQ's certificate layout:
  `<name>.key_secret` (mode 0600: its public and secret key) and `<name>.key` (public only).
  A node's pair is created when it is first needed. A secret file not owned by the user, or
  readable by group or others, is refused (`chmod 600`), as ssh refuses such keys.
* **A permissions file**, `<keystore>/permissions.json`, written by `launch` from its topology
  (or by `slip keys init LAUNCH_FILE`): for each node name, its public key and the topics it may
  publish and subscribe; plus the `slip` tools' keys (`slip`: read-only; `slip-force`: also the
  topics the launch reads but no node writes, an operator's commands).
* **Every node enforces it.** Its XPUB is a CURVE server whose ZAP handler admits only known
  public keys (those of the permissions file; without one, every public key in the keystore).
  Its SUBs are CURVE clients that pin, for each publisher, the public key the permissions give
  the publisher's announced name as the server key: the handshake succeeds only with the holder
  of that secret key, so what arrives on the connection is from that key (identity is the key,
  not the name a process gives itself). With a permissions file every node has a SUB per
  publisher and delivers a message only if that key may publish its topic (`Keyring.may_write`);
  a refused message is counted and its sender logged once (peers.py).
* **Rotation**: `slip keys rotate NAME` writes a new pair and the new public key into the
  permissions file. Every running node re-reads the keystore when it changes: ZAP refuses the old
  key from then on, and subscribers reconnect to the node pinning the new key, so a node still
  holding the old key is cut off until it is restarted (it says so once).
"""
from __future__ import annotations

import json
import os
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth      # certificates; zmq.auth.thread (asyncio) is imported by the ZAP handler

from incipient_slip.graph.discovery import GraphNameError, _unsafe, safe_name

__all__ = ["TRANSPORT_ENV", "KEYSTORE_ENV", "TRANSPORTS", "TransportError", "transport", "keystore",
           "node_keys", "rotate", "Keyring", "keyring", "write_permissions", "secure_server",
           "secure_client", "refused_clients", "INSECURE_WARNING", "TOOL_IDENTITY", "FORCE_IDENTITY",
           "PERMISSIONS_FILE", "HEARTBEAT_TOPIC"]

TRANSPORT_ENV = "SLIP_TRANSPORT"
KEYSTORE_ENV = "SLIP_KEYSTORE"
TRANSPORTS = ("ipc", "tcp", "tcp-insecure")
KEYSTORE_DIR = "keys"
PERMISSIONS_FILE = "permissions.json"
PERMISSIONS_FORMAT = "incipient-slip permissions 1"
TOOL_IDENTITY = "slip"               # the slip tools' key: read-only
FORCE_IDENTITY = "slip-force"        # the slip tools' key with --force: an operator's commands too
HEARTBEAT_TOPIC = "/heartbeat"       # every node's own: any known key may send it
INSECURE_WARNING = ("SLIP_TRANSPORT=tcp-insecure: plain TCP without authentication or encryption; "
                    "every local user can read every topic and publish on this graph")


class TransportError(GraphNameError):
    """A transport setting or key file that cannot be used (a GraphNameError: one line, exit 2)."""


def transport() -> str:
    """The transport `$SLIP_TRANSPORT` selects (TransportError for an unknown one)."""
    value = os.environ.get(TRANSPORT_ENV, "") or "ipc"
    if value not in TRANSPORTS:
        raise TransportError(f"${TRANSPORT_ENV}={value!r}: use one of {', '.join(TRANSPORTS)}")
    return value


# --- the keystore ----------------------------------------------------------------------------

def keystore(graph_dir: Path) -> Path:
    """The keystore of a graph: `$SLIP_KEYSTORE`, else `<graph dir>/keys` (created 0700); a
    directory not owned by the user or writable by others is refused."""
    given = os.environ.get(KEYSTORE_ENV)
    path = Path(given) if given else Path(graph_dir) / KEYSTORE_DIR
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    why = _unsafe(os.stat(path))
    if why:
        raise TransportError(f"keystore {path} is {why}; refusing to use it: chmod 700 {path}")
    return path


def _secret_path(store: Path, name: str) -> Path:
    return store / f"{safe_name(name)}.key_secret"


def _public_path(store: Path, name: str) -> Path:
    return store / f"{safe_name(name)}.key"


def _write_pair(store: Path, name: str, public: bytes, secret: bytes, replace: bool) -> None:
    """Writes `name`'s pair (secret file 0600, public file 0644), atomically: a concurrent first
    use agrees on one pair (`replace` False: the first one written wins)."""
    for path, text, mode in ((_secret_path(store, name), f"    secret-key = \"{secret.decode()}\"\n", 0o600),
                             (_public_path(store, name), "", 0o644)):
        tmp = store / f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
        with os.fdopen(fd, "w") as f:
            f.write(f"#   ZeroMQ CURVE {'secret' if text else 'public'} certificate of node {name} of an "
                    f"incipient-slip graph{': keep it private' if text else ''}\n"
                    f"metadata\n    name = \"{name}\"\ncurve\n    public-key = \"{public.decode()}\"\n{text}")
        if replace:
            os.replace(tmp, path)
            continue
        try:
            os.link(tmp, path)          # fails if another process was first: use its pair
        except FileExistsError:
            os.unlink(tmp)
            return
        os.unlink(tmp)


def _load_secret(path: Path) -> tuple[bytes, bytes]:
    try:
        st = os.stat(path)
    except OSError as exc:
        raise TransportError(f"CURVE key file {path}: {exc.strerror}") from None
    if st.st_uid != os.getuid() or st.st_mode & 0o077:
        raise TransportError(f"CURVE key file {path} is owned by uid {st.st_uid} with mode "
                             f"{st.st_mode & 0o777:o}; it must be yours and private: chmod 600 {path}")
    try:
        public, secret = zmq.auth.load_certificate(path)
    except (OSError, ValueError) as exc:
        raise TransportError(f"CURVE key file {path}: {exc}") from None
    if not public or not secret:
        raise TransportError(f"CURVE key file {path} holds no secret key (a public certificate?)")
    return public, secret


def node_keys(store: Path, name: str) -> tuple[bytes, bytes]:
    """(public, secret) Z85 keys of identity `name` in the keystore, created when missing."""
    if not _secret_path(store, name).exists():
        _write_pair(store, name, *zmq.curve_keypair(), replace=False)
    return _load_secret(_secret_path(store, name))


def rotate(store: Path, name: str) -> tuple[bytes | None, bytes]:
    """Gives identity `name` a new pair (and its entry in the permissions file, if any, the new
    public key); returns (old public key or None, new public key)."""
    old = _public_key(_public_path(store, name)) if _public_path(store, name).exists() else None
    public, secret = zmq.curve_keypair()
    _write_pair(store, name, public, secret, replace=True)
    path = store / PERMISSIONS_FILE
    if path.exists():
        doc = _read_permissions(path)
        if name in doc["nodes"]:
            doc["nodes"][name]["key"] = public.decode()
            _write_json(path, doc)
    return old, public


def _public_key(path: Path) -> bytes | None:
    try:
        public, _ = zmq.auth.load_certificate(path)
    except (OSError, ValueError):
        return None
    return public or None


def _write_json(path: Path, doc: dict) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    with os.fdopen(fd, "w") as f:
        json.dump(doc, f, indent=1, sort_keys=True)
        f.write("\n")
    os.replace(tmp, path)


def _read_permissions(path: Path) -> dict:
    why = _unsafe(os.stat(path))
    if why:
        raise TransportError(f"permissions file {path} is {why}; refusing to use it")
    try:
        doc = json.loads(path.read_text())
        if doc.get("format") != PERMISSIONS_FORMAT or not isinstance(doc.get("nodes"), dict):
            raise ValueError(f"not a {PERMISSIONS_FORMAT!r} document")
        for name, entry in doc["nodes"].items():
            if not isinstance(entry.get("key"), str) or len(entry["key"]) != 40 or not all(
                    isinstance(entry.get(k), list) for k in ("publish", "subscribe")):
                raise ValueError(f"node {name!r}: expected key (40 Z85 characters), publish and subscribe lists")
    except (OSError, ValueError, AttributeError) as exc:
        raise TransportError(f"permissions file {path}: {exc}") from None
    return doc


def write_permissions(store: Path, nodes: dict[str, dict[str, list[str]]], source: str) -> Path:
    """Writes (merges into) `<store>/permissions.json`: for each node name of `nodes`
    ({name: {"publish": [topics], "subscribe": [topics]}}, "*" for every topic) its public key
    (its pair created when missing) and its topics; entries of other names already there are
    kept (another launch in the same graph). Returns the file's path."""
    path = store / PERMISSIONS_FILE
    doc = _read_permissions(path) if path.exists() else {"format": PERMISSIONS_FORMAT, "nodes": {}}
    for name, topics in nodes.items():
        doc["nodes"][name] = {"key": node_keys(store, name)[0].decode(),
                              "publish": sorted(topics.get("publish", [])),
                              "subscribe": sorted(topics.get("subscribe", []))}
    doc["written_by"] = source
    _write_json(path, doc)
    return path


@dataclass(frozen=True)
class Entry:
    """One identity: its public key and the topics it may publish (None: any; a keystore without
    a permissions file restricts no topic)."""

    name: str
    key: bytes
    publish: frozenset[str] | None


class Keyring:
    """The known identities of a keystore, re-read when the keystore or its permissions file
    changes (`refresh`, a stat of each: cheap enough for every discovery scan and handshake).
    `restricted`: a permissions file gives each key its topics."""

    def __init__(self, store: Path, log=None):
        self.store = store
        self.log = log or (lambda text: print(f"[security] {text}", file=sys.stderr, flush=True))
        self._stamp = None
        self._lock = threading.Lock()
        self.restricted = False
        self.by_name: dict[str, Entry] = {}
        self.by_key: dict[bytes, list[Entry]] = {}
        self.refresh()

    def refresh(self) -> None:
        path = self.store / PERMISSIONS_FILE
        try:
            stamp = (os.stat(self.store).st_mtime_ns, os.stat(path).st_mtime_ns if path.exists() else None)
        except OSError:
            return
        with self._lock:
            if stamp == self._stamp:
                return
            try:
                entries = self._entries(path)
            except TransportError as exc:      # a broken file: keep what was known, say why
                self.log(str(exc))
                if self._stamp is None:
                    raise
                self._stamp = stamp
                return
            self._stamp = stamp
            self.restricted = path.exists()
            self.by_name = {e.name: e for e in entries}
            by_key: dict[bytes, list[Entry]] = {}
            for e in entries:
                by_key.setdefault(e.key, []).append(e)
            self.by_key = by_key

    def _entries(self, path: Path) -> list[Entry]:
        if path.exists():
            return [Entry(name, e["key"].encode(), frozenset(e["publish"]))
                    for name, e in _read_permissions(path)["nodes"].items()]
        out = []
        for cert in sorted(self.store.glob("*.key")):
            if _unsafe(os.stat(cert)):
                continue       # a public key others could have written is not a member's
            key = _public_key(cert)
            if key:
                out.append(Entry(cert.stem, key, None))
        return out

    def key_of(self, name: str) -> bytes | None:
        """The public key of identity `name`, None if it is not known."""
        entry = self.by_name.get(name) or self.by_name.get(safe_name(name))
        return entry.key if entry else None

    def admits(self, key: bytes) -> bool:
        """Whether a client with this public key may connect (ZAP)."""
        self.refresh()
        return key in self.by_key

    def names_of(self, key: bytes) -> list[str]:
        return [e.name for e in self.by_key.get(key, ())]

    def may_write(self, key: bytes, topic: str) -> bool:
        """Whether the holder of `key` may publish `topic`."""
        entries = self.by_key.get(key, ())
        if topic == HEARTBEAT_TOPIC:
            return bool(entries)
        return any(e.publish is None or "*" in e.publish or topic in e.publish for e in entries)


_keyrings: dict[Path, Keyring] = {}


def keyring(store: Path) -> Keyring:
    """The Keyring of a keystore, one per process and keystore."""
    with _lock:
        ring = _keyrings.get(store)
        if ring is None:
            ring = _keyrings[store] = Keyring(store)
        return ring


# --- ZAP ---------------------------------------------------------------------------------------
# One ZAP handler per ZeroMQ context (the ZAP endpoint is per context); each server socket names
# its graph as its ZAP domain, and the handler admits a client only with a known key of that graph.
_lock = threading.Lock()
_handlers: dict[int, "_Handler"] = {}


class _Handler:
    def __init__(self, ctx: zmq.Context):
        self.rings: dict[str, Keyring] = {}       # ZAP domain -> its keyring
        self.refused: dict[str, int] = {}
        self._logged: set[tuple[str, bytes]] = set()
        # imported here: zmq.auth.thread pulls in asyncio (~0.1 s), which only CURVE needs
        from zmq.auth.thread import ThreadAuthenticator
        self.auth = ThreadAuthenticator(ctx, log=_QuietLog())
        self.auth.start()

    def allow(self, domain: str, ring: Keyring) -> None:
        self.rings[domain] = ring
        self.auth.configure_curve_callback(domain, credentials_provider=self)

    def callback(self, domain: str, key: bytes) -> bool:      # ThreadAuthenticator: key in Z85
        ring = self.rings.get(domain)
        ok = ring is not None and ring.admits(key)
        if not ok:
            self.refused[domain] = self.refused.get(domain, 0) + 1
            if (domain, key) not in self._logged:     # once per key
                self._logged.add((domain, key))
                print(f"[security] refused a CURVE client whose key {key.decode()[:8]}... is not "
                      f"known in {ring.store if ring else 'this graph'} ({self.refused[domain]} "
                      f"refused in graph {domain})", file=sys.stderr, flush=True)
        return ok


class _QuietLog:
    """ThreadAuthenticator logs every handshake at debug level; only its problems are kept."""

    def debug(self, *args, **kw):
        pass

    info = debug

    def warning(self, msg, *args, **kw):
        print(f"[security] {msg % args if args else msg}", file=sys.stderr, flush=True)

    error = warning
    exception = warning


def _handler(ctx: zmq.Context) -> _Handler:
    with _lock:
        h = _handlers.get(id(ctx))
        if h is None:
            h = _handlers[id(ctx)] = _Handler(ctx)
        return h


def secure_server(sock: zmq.Socket, keys: tuple[bytes, bytes], domain: str, ring: Keyring) -> None:
    """Makes `sock` (before bind) a CURVE server with this node's pair that admits only clients
    with a key `ring` knows."""
    _handler(sock.context).allow(domain, ring)
    sock.setsockopt(zmq.ZAP_DOMAIN, domain.encode())
    sock.curve_secretkey = keys[1]
    sock.curve_publickey = keys[0]
    sock.curve_server = True


def secure_client(sock: zmq.Socket, keys: tuple[bytes, bytes]) -> None:
    """Makes `sock` a CURVE client with this node's pair; the server key is set per connection
    (`pin`), before each connect."""
    sock.curve_publickey, sock.curve_secretkey = keys
    # a publisher whose key is not the one pinned fails every handshake: back off, don't spin
    sock.setsockopt(zmq.RECONNECT_IVL_MAX, 5000)


def pin(sock: zmq.Socket, server_key: bytes) -> None:
    """The server key the next `connect` of `sock` must find (libzmq copies it per connection)."""
    sock.curve_serverkey = server_key


def refused_clients(ctx: zmq.Context, domain: str) -> int:
    """How many clients the ZAP handler of `ctx` refused for graph `domain`."""
    h = _handlers.get(id(ctx))
    return h.refused.get(domain, 0) if h else 0
