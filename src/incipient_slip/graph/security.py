"""Transport security: CURVE authentication and encryption of a graph's TCP sockets.

`$SLIP_TRANSPORT` selects the transport: `ipc` (default: Unix sockets in the 0700 graph
directory, which only the user reaches), `tcp` (127.0.0.1, every socket CURVE-authenticated and
encrypted with the graph's key pair) or `tcp-insecure` (plain TCP, with a warning: every local
user can connect, read every topic and publish).

One key pair per graph (as ZeroMQ's CURVE/ZAP and SROS2 do it per enclave): `<graph dir>/curve.key`
(mode 0600, created by the first node that needs it, in ZeroMQ's certificate format), or the file
named by `$SLIP_CURVE_KEYS` (a graph across hosts: copy the file). A key file not owned by the
user or readable by others is refused, as ssh refuses such keys. Every node's XPUB is a CURVE
server with the graph's secret key; every SUB is a CURVE client holding the graph's key pair and
trusting only the graph's server key; a ZAP handler admits only clients that hold the graph's key.
A client with any other key is refused and counted (`refused_clients`), a process without the key
file can neither read nor publish (its handshakes fail).
"""
from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import zmq
import zmq.auth      # certificates; zmq.auth.thread (asyncio) is imported by the ZAP handler

from incipient_slip.graph.discovery import GraphNameError

__all__ = ["TRANSPORT_ENV", "KEYS_ENV", "TRANSPORTS", "TransportError", "transport", "graph_keys",
           "secure_server", "secure_client", "refused_clients", "INSECURE_WARNING"]

TRANSPORT_ENV = "SLIP_TRANSPORT"
KEYS_ENV = "SLIP_CURVE_KEYS"
TRANSPORTS = ("ipc", "tcp", "tcp-insecure")
KEY_FILE = "curve.key"
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


def graph_keys(directory: Path) -> tuple[bytes, bytes]:
    """(public, secret) Z85 keys of the graph: from `$SLIP_CURVE_KEYS`, else `<directory>/curve.key`,
    created (mode 0600, atomically: concurrent nodes agree on one pair) when missing."""
    given = os.environ.get(KEYS_ENV)
    path = Path(given) if given else directory / KEY_FILE
    if not given and not path.exists():
        public, secret = zmq.curve_keypair()
        tmp = directory / f".{KEY_FILE}.{os.getpid()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write("#   ZeroMQ CURVE secret certificate of an incipient-slip graph: keep it private\n"
                    f"metadata\ncurve\n    public-key = \"{public.decode()}\"\n"
                    f"    secret-key = \"{secret.decode()}\"\n")
        try:
            os.link(tmp, path)          # fails if another node was first: use its pair
        except FileExistsError:
            pass
        finally:
            os.unlink(tmp)
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


# One ZAP handler per ZeroMQ context (the ZAP endpoint is per context); each server socket names
# its graph as its ZAP domain, and the handler admits a client only with that graph's public key.
_lock = threading.Lock()
_handlers: dict[int, "_Handler"] = {}


class _Handler:
    def __init__(self, ctx: zmq.Context):
        self.allowed: dict[str, bytes] = {}      # ZAP domain -> the graph's public key (Z85)
        self.refused: dict[str, int] = {}
        # imported here: zmq.auth.thread pulls in asyncio (~0.1 s), which only CURVE needs
        from zmq.auth.thread import ThreadAuthenticator
        self.auth = ThreadAuthenticator(ctx, log=_QuietLog())
        self.auth.start()

    def allow(self, domain: str, public_key: bytes) -> None:
        self.allowed[domain] = public_key
        self.auth.configure_curve_callback(domain, credentials_provider=self)

    def callback(self, domain: str, key: bytes) -> bool:      # ThreadAuthenticator: key in Z85
        ok = self.allowed.get(domain) == key
        if not ok:
            self.refused[domain] = self.refused.get(domain, 0) + 1
            print(f"[security] refused a CURVE client with a key that is not the graph's "
                  f"({self.refused[domain]} refused in graph {domain})", file=sys.stderr, flush=True)
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


def secure_server(sock: zmq.Socket, keys: tuple[bytes, bytes], domain: str) -> None:
    """Makes `sock` (before bind) a CURVE server that admits only clients with the graph's key."""
    _handler(sock.context).allow(domain, keys[0])
    sock.setsockopt(zmq.ZAP_DOMAIN, domain.encode())
    sock.curve_secretkey = keys[1]
    sock.curve_publickey = keys[0]
    sock.curve_server = True


def secure_client(sock: zmq.Socket, keys: tuple[bytes, bytes]) -> None:
    """Makes `sock` (before connect) a CURVE client with the graph's key, trusting its server key."""
    sock.curve_publickey, sock.curve_secretkey = keys
    sock.curve_serverkey = keys[0]


def refused_clients(ctx: zmq.Context, domain: str) -> int:
    """How many clients the ZAP handler of `ctx` refused for graph `domain`."""
    h = _handlers.get(id(ctx))
    return h.refused.get(domain, 0) if h else 0
