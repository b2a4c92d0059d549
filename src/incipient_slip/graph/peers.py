"""Peers of a node (rclpy's discovery and graph events): announcing this node, connecting to the
publishers it reads (only to the launch's writers of its inputs), the hello handshake by which a
source knows its readers are subscribed, and the subscription news its XPUB reports.

Over tcp (security.py) each connection pins the public key of the identity its publisher
announces, so the key, not the name, is the publisher's identity: with a permissions file a
message is delivered only if that key may publish its topic, and a hello counts only from the
key of the node it names.

`Peers` is a base of `runtime.Node` and uses its sockets and tables.
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import zmq

from incipient_slip.graph import discovery, security
from incipient_slip.graph.executor import POLL_S, _open_nodes
from incipient_slip.graph.params import ParamError

__all__ = ["Peers", "Peer", "READERS_ENV", "WRITERS_ENV", "HELLO", "READY_TIMEOUT_S", "DISCONNECT_GRACE_S"]

DISCONNECT_GRACE_S = 2.0  # how long a withdrawn publisher stays connected so its last frames are read
LINGER_MS = 500           # longest close() waits to flush queued messages
HWM = 100_000             # per-peer queue, messages; P_AC at 100 frames/s is tiny beside it
READY_TIMEOUT_S = 10.0    # default wait for the named readers before a source starts anyway
ANY_TOPIC = discovery.ANY_TOPIC
# Set by the launcher for each node: JSON {output topic after remaps: [reader node names]}, the
# readers in this launch that `wait_for_readers` waits for. Unset (a node started by hand): none.
READERS_ENV = "SLIP_READERS"
# Set by the launcher for each node: JSON {input topic after remaps: [writer node names]}. A node
# accepts those topics only from those nodes: it does not connect to a node that announces one of
# them without being its writer (a forged command or state; counted in `refused_writers`, one warning
# each). Unset (a node started by hand, a recorder): every publisher is accepted.
WRITERS_ENV = "SLIP_WRITERS"
# Each node, once its subscriptions are made, also subscribes HELLO + its name: a subscription no
# one publishes on, whose XPUB message tells a publisher WHICH node is now subscribed (plain XPUB
# subscription messages carry no identity). 0xFF sorts after every "/..." topic, which matters:
# a SUB that connects late sends its subscriptions in ascending byte order (libzmq's trie), and a
# SUB already connected sends each new one in the order it was made, so when a publisher reads a
# node's hello, that node's other subscriptions have reached it before (same pipe, in order).
HELLO = b"\xffhello/"



class Peers:
    """The discovery half of `runtime.Node`: announcement, connections, hello handshake."""

    def _join_graph(self, graph_dir, context: zmq.Context | None) -> None:
        """Opens this node's sockets in its graph directory: the XPUB bound on the transport's
        endpoint (CURVE on tcp), the SUB that connects to publishers as discovery finds them."""
        self._dir = discovery.graph_dir() if graph_dir is None else Path(graph_dir)
        self._dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        discovery.check_graph_dir(self._dir)
        self._ctx = context or zmq.Context.instance()
        self._xpub = self._ctx.socket(zmq.XPUB)
        self._xpub.setsockopt(zmq.XPUB_VERBOSE, 1)
        self._xpub.setsockopt(zmq.XPUB_VERBOSER, 1)
        self._xpub.setsockopt(zmq.SNDHWM, HWM)
        self._xpub.setsockopt(zmq.LINGER, LINGER_MS)
        instance = discovery.new_instance()
        transport = security.transport()
        # tcp: every socket CURVE-authenticated and encrypted with this node's own key pair, the
        # peers' keys and topics from the keystore and its permissions file (security.py)
        self._keyring: security.Keyring | None = None
        self._keys = None
        self._pinned: dict[str, bytes] = {}      # endpoint -> the server key its connection pinned
        self._said_rotated = False
        if transport == "tcp":
            self._keyring = security.keyring(security.keystore(self._dir))
            self._keys = security.node_keys(self._keyring.store, self._identity)
            self._keyring.refresh()
            if self._keyring.restricted and self._keyring.key_of(self._identity) != self._keys[0]:
                self.warn(f"identity {self._identity} has no entry with its key in "
                          f"{self._keyring.store / security.PERMISSIONS_FILE}: the other nodes "
                          f"refuse it (a node of the launch that wrote it, or slip keys init)")
            security.secure_server(self._xpub, self._keys, str(self._dir), self._keyring)
        elif transport == "tcp-insecure":
            self.warn(security.INSECURE_WARNING)
        if transport != "ipc":
            port = self._xpub.bind_to_random_port("tcp://127.0.0.1")
            endpoint = f"tcp://127.0.0.1:{port}"
        else:
            endpoint = discovery.ipc_endpoint(self._dir, self.name, os.getpid(), instance)
            self._xpub.bind(endpoint)
        self._sub = self._new_sub()
        self._rcvtimeo = -1
        # A node with writers (a launch's), or over tcp with a permissions file, gives each
        # publisher it connects to a SUB of its own, so that every message is checked against the
        # connection it came on (`_writer_refusal`, `_key_refusal`)
        self._per_peer = bool(self._writers) or bool(self._keyring and self._keyring.restricted)
        self._peer_subs: dict[str, zmq.Socket] = {}     # endpoint -> its own SUB
        self._peer_of: dict[zmq.Socket, Peer] = {}
        self._poller = zmq.Poller()
        self._subscribed: dict[bytes, int] = {}     # prefix -> times subscribed, in order made
        self.refused_messages = 0
        self.refused_hellos = 0        # over tcp: hellos naming a node whose key the sender lacks
        self._info = discovery.NodeInfo(self.name, os.getpid(), endpoint, started_ns=time.time_ns(),
                                        pidns=discovery.namespace("pid"), netns=discovery.namespace("net"),
                                        params=dict(self.params),   # for `slip param`
                                        instance=instance,
                                        identity="" if self._identity == self.name else self._identity)
        self._discovery = discovery.Discovery(self._dir, log=lambda text: self.warn(text))
        self._connected: set[str] = set()
        self._retiring: dict[str, float] = {}   # endpoint -> monotonic time to disconnect
        self._refused_endpoints: set[str] = set()
        self._next_scan = 0.0
        _open_nodes.add(self)

    def _new_sub(self) -> zmq.Socket:
        sub = self._ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.RCVHWM, HWM)
        sub.setsockopt(zmq.LINGER, 0)
        if self._keys:
            security.secure_client(sub, self._keys)
        return sub

    def _subscribe(self, prefix: bytes, on: bool = True) -> None:
        """(Un)subscribes `prefix` on every SUB of this node, and remembers it for those to come."""
        option = zmq.SUBSCRIBE if on else zmq.UNSUBSCRIBE
        for sub in (self._sub, *self._peer_subs.values()):
            sub.setsockopt(option, prefix)
        n = self._subscribed.get(prefix, 0) + (1 if on else -1)
        if n > 0:
            self._subscribed[prefix] = n
        else:
            self._subscribed.pop(prefix, None)

    def _connect(self, endpoint: str) -> None:
        info = self._discovery.info_of(endpoint)
        # over tcp the connection pins the key of the identity the publisher announces: only the
        # holder of its secret key completes the handshake (`_accepts` made sure it is known)
        key = self._keyring.key_of(_identity(info)) if self._keyring is not None else None
        if key is not None:
            self._pinned[endpoint] = key
        if not self._per_peer:
            if key is not None:
                security.pin(self._sub, key)
            self._sub.connect(endpoint)
            return
        sub = self._new_sub()
        for prefix, n in self._subscribed.items():
            for _ in range(n):
                sub.setsockopt(zmq.SUBSCRIBE, prefix)
        if key is not None:
            security.pin(sub, key)
        sub.connect(endpoint)
        self._peer_subs[endpoint] = sub
        self._peer_of[sub] = Peer(info, key)
        self._poller.register(sub, zmq.POLLIN)

    def _disconnect(self, endpoint: str) -> None:
        self._pinned.pop(endpoint, None)
        sub = self._peer_subs.pop(endpoint, None)
        if sub is None:
            try:
                self._sub.disconnect(endpoint)
            except zmq.ZMQError:
                pass
            return
        self._poller.unregister(sub)
        del self._peer_of[sub]
        sub.close(linger=0)

    def _close_subs(self) -> None:
        self._sub.close(linger=0)
        for endpoint in list(self._peer_subs):
            self._disconnect(endpoint)

    @property
    def readers(self) -> dict[str, list[str]]:
        """{output topic: names of the nodes of this launch that read it} (the launcher's
        topology; empty for a node started by hand)."""
        return self._readers

    def wait_before_first(self, pub, by_hand: int, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Before a message that must not be lost: the readers this launch names
        (`wait_for_readers`) or, started by hand, `by_hand` subscribers of `pub`; a warning, and
        on, when they do not come."""
        if self.readers:
            self.wait_for_readers(timeout_s)
        elif not pub.wait_for_subscribers(by_hand, timeout_s):
            self.warn(f"too few readers of {pub.topic}; sending anyway")

    def wait_for_readers(self, timeout_s: float = READY_TIMEOUT_S) -> bool:
        """True once every node of this launch that reads one of this node's outputs has
        subscribed here (its hello arrived, so its subscriptions are in place); at once when there
        is no launch topology. False on timeout (with a warning naming the missing readers) or
        shutdown. Call it after the node's own subscriptions are made, before the first message
        that must not be lost: it says this node's hello too, so two nodes that wait for each
        other both get through."""
        self._say_hello()
        if not self._reader_names():
            return True
        deadline = time.monotonic() + timeout_s
        while True:
            missing = self._missing_readers()
            if not missing:
                return True
            left = deadline - time.monotonic()
            if left <= 0 or self._stop:
                if not self._stop:
                    self.warn(f"readers {', '.join(missing)} not subscribed after {timeout_s:g} s; "
                              f"starting without them")
                return False
            self._xpub.poll(min(left, POLL_S) * 1000.0, zmq.POLLIN)

    def missing_readers(self) -> list[str]:
        """The launch's named readers of this node's outputs that have not subscribed yet, without
        blocking: for nodes that wait inside a timer (`wait_for_readers` is the blocking form).
        Says this node's hello the first time."""
        if not self._said_hello:
            self._say_hello()
        return self._missing_readers()

    def _reader_names(self) -> list[str]:
        return sorted({n for readers in self._readers.values() for n in readers} - {self.name})

    def _missing_readers(self) -> list[str]:
        if time.monotonic() >= self._next_scan:
            self._discover()      # our own subscriptions must connect too, or we deadlock
        self._drain_xpub()
        return [n for n in self._reader_names() if not self._sub_counts.get(HELLO + n.encode())]

    def _announce(self) -> None:
        discovery.announce(self._dir, self._info)

    def _say_hello(self) -> None:
        """Subscribes this node's hello topic, last (see HELLO); again after a later subscription,
        so that a hello always follows every subscription made before it."""
        hello = HELLO + self.name.encode()
        if self._said_hello:
            self._subscribe(hello, False)
        self._subscribe(hello)
        self._said_hello = True

    def _after_subscribe(self) -> None:
        if self._said_hello:
            self._say_hello()
        self._announce()
        self._discover()

    def _discover(self) -> None:
        self._next_scan = time.monotonic() + POLL_S
        if self._keyring is not None:
            self._follow_keys()
        added, removed = self._discovery.changes(
            self._accepts if self._writers or self._keyring is not None else None)
        now = time.monotonic()
        for endpoint in added:
            self._retiring.pop(endpoint, None)
            if endpoint not in self._connected:
                self._connect(endpoint)
                self._connected.add(endpoint)
        # A publisher that withdrew may still have frames in our pipe: ZeroMQ discards them on
        # disconnect, so disconnect only after a grace period in which the loop reads them.
        # A publisher refused as a forger is cut at once (no grace: its frames are not wanted).
        for endpoint in removed:
            if endpoint in self._connected:
                forged = endpoint in self._refused_endpoints
                self._retiring.setdefault(endpoint, now if forged else now + DISCONNECT_GRACE_S)
        for endpoint, due in list(self._retiring.items()):
            if due <= now:
                del self._retiring[endpoint]
                self._disconnect(endpoint)
                self._connected.discard(endpoint)
        for peer in self._peer_of.values():       # the announcements as they are now
            peer.info = self._discovery.info_of(peer.info.endpoint) or peer.info

    def _follow_keys(self) -> None:
        """Re-reads the keystore if it changed; a connection whose publisher's identity now has
        another key (rotated) is cut at once and made again, pinning the new key (so a process
        still holding the old one gets nothing through). Says once if this node's own key was
        rotated: its peers now refuse it until it is restarted."""
        ring = self._keyring
        ring.refresh()
        for endpoint, key in list(self._pinned.items()):
            info = self._discovery.info_of(endpoint)
            if info is None or ring.key_of(_identity(info)) == key:
                continue
            self.warn(f"the key of {_identity(info)} changed (slip keys rotate): reconnecting to "
                      f"{info.name} (pid {info.pid}) with the new one")
            self._disconnect(endpoint)
            self._connected.discard(endpoint)
            self._retiring.pop(endpoint, None)
            self._discovery.endpoints.discard(endpoint)      # offered again by changes()
        if not self._said_rotated and ring.key_of(self._identity) not in (None, self._keys[0]):
            self._said_rotated = True
            self.warn(f"the key of {self._identity} was rotated; this process holds the old one, "
                      f"which the other nodes now refuse: restart it")

    @property
    def refused_clients(self) -> int:
        """Connections to this node's graph refused by CURVE authentication (a key the keystore
        or its permissions file does not know), counted per process and graph."""
        return security.refused_clients(self._ctx, str(self._dir))

    def _accepts(self, info: discovery.NodeInfo) -> bool:
        """Whether to connect to an announced node: over tcp only to one whose identity has a
        known key; given the launch's writers of our inputs, never to one that announces an
        input of ours without being its declared writer (counted and logged once), else to the
        declared writers and to the publishers of the inputs that have none (an operator's
        command) or of every topic for a node that reads them all."""
        if self._keyring is not None and self._keyring.key_of(_identity(info)) is None:
            self._refuse(info, f"publisher {info.name} (pid {info.pid}) refused: no key for "
                               f"identity {_identity(info)} in {self._key_source()}")
            return False
        writers = self._writers
        if not writers:
            return True
        for topic in info.publishes:
            why = self._writer_refusal(info, topic)
            if why:
                self._refuse(info, f"publisher {info.name} (pid {info.pid}) refused: it announces {why}")
                self._refused_endpoints.add(info.endpoint)
                return False
        if any(info.name in names for names in writers.values()):
            return True
        reads = self._info.subscribes
        return ANY_TOPIC in reads or any(t in reads for t in info.publishes)

    def _writer_refusal(self, info: discovery.NodeInfo, topic: str) -> str:
        """Why the node announced by `info` may not write `topic` to this one ("" if it may): a
        topic must be one it announces and, when the launch names the topic's writers, it must be
        one of them."""
        if topic not in info.publishes:
            return f"{topic}, which it does not announce"
        writers = self._writers.get(topic)
        if writers and info.name not in writers:
            return f"{topic}, whose writer in this launch is {' or '.join(writers)}"
        return ""

    def _takes(self, peer: "Peer", topic: str) -> bool:
        """Whether a message on `topic` that came on `peer`'s connection is delivered; a refused
        one is counted (`refused_messages`) and logged once per peer (`refused_writers`)."""
        if topic in peer.topics:
            return True
        why = self._writer_refusal(peer.info, topic) or self._key_refusal(peer, topic)
        if why:     # a publisher announces a topic before it sends on it: look again at once
            self._discover()
            why = self._writer_refusal(peer.info, topic) or self._key_refusal(peer, topic)
        if not why:
            peer.topics.add(topic)
            return True
        self.refused_messages += 1
        self._refuse(peer.info, f"messages from {peer.info.name} (pid {peer.info.pid}) refused: "
                                f"it sent {why}")
        return False

    def _key_refusal(self, peer: "Peer", topic: str) -> str:
        """Why the key `peer`'s connection authenticated may not write `topic` ("" if it may)."""
        if peer.key is None or self._keyring.may_write(peer.key, topic):
            return ""
        names = ", ".join(self._keyring.names_of(peer.key)) or "a key no longer known"
        return f"{topic}, which its key (identity {names}) may not publish in {self._key_source()}"

    def _key_source(self) -> str:
        ring = self._keyring
        return str(ring.store / security.PERMISSIONS_FILE) if ring.restricted else f"keystore {ring.store}"

    def _refuse(self, info: discovery.NodeInfo, why: str) -> None:
        key = (info.name, info.pid)
        if key not in self.refused_writers:
            self.refused_writers[key] = why
            self.warn(f"{why} ({len(self.refused_writers)} refused)")

    def _drain_xpub(self) -> None:
        counts = self._sub_counts
        keyed = self._keyring is not None
        while True:
            try:
                if keyed:       # over tcp the frame carries the subscriber's key (ZAP's User-Id)
                    frame = self._xpub.recv(zmq.NOBLOCK, copy=False)
                    msg = frame.bytes
                else:
                    msg = self._xpub.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if not msg:
                continue
            prefix = msg[1:]
            if keyed and prefix.startswith(HELLO) and not self._hello_is_its_own(frame, prefix, msg[0] == 1):
                continue
            if msg[0] == 1:
                counts[prefix] = counts.get(prefix, 0) + 1
                for pub in self._latched:
                    if pub.last is not None and pub.frame.startswith(prefix):
                        pub._send(pub.last)
            elif msg[0] == 0:
                counts[prefix] = max(0, counts.get(prefix, 0) - 1)

    def _hello_is_its_own(self, frame: zmq.Frame, prefix: bytes, subscribe: bool) -> bool:
        """Over tcp, whether a hello (or its withdrawal) naming a node with a key came from that
        key: a process with another key cannot answer for a reader this node waits for (it would
        start before the reader listens). A name without a key (a tool's) is taken as it is, and
        so is a withdrawal ZeroMQ makes when a connection ends (it carries no key)."""
        name = prefix[len(HELLO):].decode(errors="replace")
        expected = self._keyring.key_of(name)
        if expected is None:
            return True
        try:
            key = frame.get("User-Id").encode()
        except zmq.ZMQError:
            return not subscribe
        if key == expected:
            return True
        if not subscribe:
            return False
        self.refused_hellos += 1
        self.warn(throttle_s=60.0, key=("hello", name, key),
                  text=f"a subscriber with the key of {', '.join(self._keyring.names_of(key)) or 'no known identity'} "
                       f"said it is {name}: not counted as {name}'s subscription")
        return False

    def _subscribers_of(self, frame: bytes) -> int:
        return sum(n for prefix, n in self._sub_counts.items() if frame.startswith(prefix))

    def _wait_subscribers(self, frame: bytes, n: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while True:
            # Keep discovering while we wait: our own subscriptions must connect to the nodes
            # that are joining too, or their first messages to us would be lost.
            if time.monotonic() >= self._next_scan:
                self._discover()
            self._drain_xpub()
            if self._subscribers_of(frame) >= n:
                return True
            left = deadline - time.monotonic()
            if left <= 0 or self._stop:
                return False
            self._xpub.poll(min(left, POLL_S) * 1000.0, zmq.POLLIN)


class Peer:
    """A publisher this node connected to on a SUB of its own: its announcement as last scanned,
    and the topics already found to be its to send here."""

    __slots__ = ("info", "topics", "key")

    def __init__(self, info: discovery.NodeInfo, key: bytes | None = None):
        # key: over tcp, the public key the connection pinned, which the handshake proved
        self.info, self.topics, self.key = info, set(), key


def _identity(info: discovery.NodeInfo) -> str:
    """The keystore identity a node announces (its name unless it holds another's key: a tool)."""
    return info.identity or info.name


def _table_from_env(env: str, node: str) -> dict[str, list[str]]:
    text = os.environ.get(env)
    if not text:
        return {}
    try:
        table = json.loads(text)
        return {str(t): [str(n) for n in names] for t, names in table.items()}
    except (ValueError, AttributeError, TypeError):
        raise ParamError(f"node {node!r}: ${env} is not JSON {{topic: [node names]}}: "
                         f"{text[:80]!r}") from None

