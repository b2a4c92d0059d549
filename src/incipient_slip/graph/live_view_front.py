"""A thin front for the live view's WebSocket server: every Foxglove WebSocket client gets in.

foxglove-sdk (0.30.3, and no option of its Python API changes it) accepts only the subprotocol
`foxglove.sdk.v1` and answers any other handshake with HTTP 400. The protocol is the same under
its older name `foxglove.websocket.v1`, which the official `@foxglove/ws-protocol` client, older
Foxglove and Lichtblick builds offer. `SubprotocolFront` listens on the public address, reads
each client's HTTP upgrade request, offers the SDK (on a loopback port of its own) the name it
knows, gives the client back the name it offered, and from then on copies bytes both ways,
unchanged. It also follows what it sends to the clients, so that the bridge can wait until what
the SDK queued has gone out before it stops (`drain`).

A request that is not a complete HTTP head within HEAD_MAX bytes or HEAD_TIMEOUT_S is closed
and counted (`refused`); whatever else the client offers goes to the SDK as it is (which answers
400 to a subprotocol it does not speak).
"""
from __future__ import annotations

import re
import socket
import threading
import time

__all__ = ["SubprotocolFront", "SDK_SUBPROTOCOL", "LEGACY_SUBPROTOCOL"]

SDK_SUBPROTOCOL = b"foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = b"foxglove.websocket.v1"
HEAD_MAX = 64 * 1024            # an HTTP upgrade request is a few hundred bytes
HEAD_TIMEOUT_S = 10.0
_CHUNK = 256 * 1024
_PROTOCOL_LINE = re.compile(rb"^sec-websocket-protocol:[ \t]*(.*?)[ \t]*$", re.I | re.M)


class SubprotocolFront:
    """Listens on (host, port) and relays each connection to the SDK at 127.0.0.1:`upstream_port`."""

    def __init__(self, host: str, port: int, upstream_port: int):
        self.upstream = ("127.0.0.1", upstream_port)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._listener = socket.socket(family, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind((host, port))
        self._listener.listen(16)
        self.port = self._listener.getsockname()[1]
        self.refused = 0                     # connections closed before a complete request head
        self.renamed = 0                     # handshakes offered as foxglove.websocket.v1
        self.last_sent = time.monotonic()    # when the last byte went to a client
        self.sending = 0                     # copies to a client holding bytes the client has not taken
        self._sockets: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._closed = False
        threading.Thread(target=self._accept, name="live-view-front", daemon=True).start()

    def quiet_for(self) -> float:
        """Seconds since the last byte went to a client."""
        return time.monotonic() - self.last_sent

    def drain(self, quiet_s: float, timeout_s: float) -> bool:
        """Waits until every client took what was copied to it and no byte has gone out for
        `quiet_s` (what the SDK queued has gone out); True then. False once bytes wait for a client
        that took none for `timeout_s` (a stalled client is not waited for). A client that reads
        slowly is still reading: a wait for its socket to take the next bytes is not quiet (a loaded
        make test-load run closed on a test client 0.3 s behind, which lost the run's last 47 estimates)."""
        while True:
            idle = self.quiet_for()
            if not self.sending and idle >= quiet_s:
                return True
            if self.sending and idle > timeout_s:
                return False
            time.sleep(min(quiet_s, 0.05))

    def close(self, grace_s: float = 0.0) -> None:
        """Stops accepting; waits up to `grace_s` for the relayed connections to end on their own
        (the server's close frames reaching the clients), then cuts the rest."""
        self._closed = True
        deadline = time.monotonic() + grace_s
        while time.monotonic() < deadline:
            with self._lock:
                if not self._sockets:
                    break
            time.sleep(0.01)
        with self._lock:
            sockets, self._sockets = list(self._sockets), set()
        for sock in [self._listener, *sockets]:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            sock.close()

    def _track(self, sock: socket.socket) -> bool:
        with self._lock:
            if self._closed:
                sock.close()
                return False
            self._sockets.add(sock)
            return True

    def _forget(self, *socks: socket.socket) -> None:
        with self._lock:
            for sock in socks:
                self._sockets.discard(sock)
        for sock in socks:
            sock.close()

    def _accept(self) -> None:
        while not self._closed:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            if self._track(client):
                threading.Thread(target=self._serve, args=(client,), name="live-view-client",
                                 daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        upstream = None
        try:
            client.settimeout(HEAD_TIMEOUT_S)
            head, rest = _read_head(client)
            if head is None:
                self.refused += 1
                return
            offered = _offered(head)
            legacy = LEGACY_SUBPROTOCOL in offered and SDK_SUBPROTOCOL not in offered
            if legacy:
                self.renamed += 1
                head = _PROTOCOL_LINE.sub(lambda m: b"Sec-WebSocket-Protocol: " + SDK_SUBPROTOCOL + b"\r", head, 1)
            upstream = socket.create_connection(self.upstream, timeout=HEAD_TIMEOUT_S)
            if not self._track(upstream):
                return
            upstream.sendall(head + rest)
            reply, rest = _read_head(upstream)
            if reply is None:
                return
            if legacy:
                reply = _PROTOCOL_LINE.sub(lambda m: b"Sec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL + b"\r", reply, 1)
            client.sendall(reply + rest)
            client.settimeout(None)
            upstream.settimeout(None)
            for sock in (client, upstream):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            threading.Thread(target=self._copy, args=(client, upstream, False), daemon=True,
                             name="live-view-in").start()
            self._copy(upstream, client, True)
        except OSError:
            pass
        finally:
            self._forget(*[s for s in (client, upstream) if s is not None])

    def _copy(self, src: socket.socket, dst: socket.socket, to_client: bool) -> None:
        """Copies until either side closes, then closes the other direction too."""
        try:
            while True:
                data = src.recv(_CHUNK)
                if not data:
                    break
                if not to_client:
                    dst.sendall(data)
                    continue
                with self._lock:
                    self.sending += 1
                try:
                    view = memoryview(data)
                    while view:                      # each part the client takes is progress
                        view = view[dst.send(view):]
                        self.last_sent = time.monotonic()
                finally:
                    with self._lock:
                        self.sending -= 1
        except OSError:
            pass
        for sock in (src, dst):
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


def _read_head(sock: socket.socket) -> tuple[bytes | None, bytes]:
    """(the HTTP head up to and with its blank line, the bytes read after it); (None, b"") when
    the peer closed or sent more than HEAD_MAX bytes without one."""
    data = b""
    while True:
        end = data.find(b"\r\n\r\n")
        if end >= 0:
            return data[:end + 4], data[end + 4:]
        if len(data) > HEAD_MAX:
            return None, b""
        try:
            chunk = sock.recv(4096)
        except OSError:         # a timeout among them
            return None, b""
        if not chunk:
            return None, b""
        data += chunk


def _offered(head: bytes) -> set[bytes]:
    """The subprotocols a request head offers (every Sec-WebSocket-Protocol line, comma lists)."""
    return {name.strip() for line in _PROTOCOL_LINE.findall(head) for name in line.split(b",")}
