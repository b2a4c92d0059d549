"""SLIP_TRANSPORT=tcp: a key pair per node, the launch's permissions file, identity by key (issue
31 item 3). Real sockets; the forgers are processes of their own."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time

import pytest
import zmq

from incipient_slip import messages as M
from incipient_slip.graph import security
from incipient_slip.graph.launch.resolve import find_launch_file, load
from incipient_slip.graph.runtime import Node
from waiting import spin_until

# rig_sim as stabilize.yaml starts it: /grip/command only from grip_controller
RIG_WRITERS = {M.GripCommand.TOPIC: ["grip_controller"]}

# A process that calls itself grip_controller and sends a 99 kPa command every 20 ms, holding the
# key of identity argv[1] ("": its own name's); it prints "subscribed" when a reader subscribes.
FORGER = """
import sys, time
from incipient_slip import messages as M
from incipient_slip.graph.runtime import Node
node = Node("grip_controller", identity=sys.argv[1] or None, heartbeat_s=0)
pub = node.create_publisher(M.GripCommand)
said = False
print("ready", flush=True)
for i in range(100000):
    node.spin_once(0.02)
    if pub.subscriber_count() and not said:
        said = True
        print("subscribed", flush=True)
    pub.publish(M.GripCommand(normal_force_kpa=99.0, period=i, reason="forged"))
"""


@pytest.fixture
def tcp(graph, monkeypatch):
    """A tcp graph whose keystore holds the permissions stabilize.yaml's launch writes."""
    monkeypatch.setenv("SLIP_TRANSPORT", "tcp")
    monkeypatch.delenv("SLIP_KEYSTORE", raising=False)
    graph.env = dict(graph.env, SLIP_TRANSPORT="tcp")
    graph.env.pop("SLIP_KEYSTORE", None)
    graph.store = security.keystore(graph.dir)
    security.write_permissions(graph.store, load(find_launch_file("stabilize.yaml")).topology.permissions(), "test")
    return graph


def until(predicate, nodes, procs=(), what="", timeout_s=30.0):
    def spin():
        for node in nodes:
            node.spin_once(0.01)
    spin_until(spin, predicate, timeout_s, procs, what)


def _forger(graph, identity: str, keystore=None):
    env = ["env", f"SLIP_KEYSTORE={keystore}"] if keystore else []
    proc = graph.spawn([*env, "python", "-c", FORGER, identity], text=True)
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
    return proc


@pytest.mark.parametrize("stolen", ["estimator", security.TOOL_IDENTITY])
def test_a_valid_key_of_another_node_cannot_command_the_rig(tcp, stolen):
    """A process holding a valid key (the estimator's, or the tools') that calls itself
    grip_controller: before, the name was the identity and any holder of the graph's one key was
    admitted, so rig_sim applied its 99 kPa. Now (a) it says whose key it holds: the connection is
    that key's, and the key may not publish /grip/command (counted, logged once); (b) it claims
    grip_controller's identity: rig_sim pins grip_controller's key, no handshake completes."""
    with Node("rig_sim", writers=RIG_WRITERS) as rig, Node("grip_controller") as ctl:
        got = []
        rig.create_subscription(M.GripCommand, got.append)
        real = ctl.create_publisher(M.GripCommand)
        honest = _forger(tcp, stolen)                    # (a): announces identity `stolen`
        until(lambda: rig.refused_messages >= 2, [rig, ctl], [honest], "the forged commands refused")
        (pid, why), = [(p, w) for (n, p), w in rig.refused_writers.items()]
        assert pid == honest.pid and f"identity {stolen}) may not publish" in why
        # (b): a copy of the stolen secret filed as grip_controller's, as a thief would
        thief = tcp.dir / "thief"
        shutil.copytree(tcp.store, thief)
        shutil.copy(tcp.store / f"{stolen}.key_secret", thief / "grip_controller.key_secret")
        claiming = _forger(tcp, "", keystore=thief)
        until(lambda: any(p.info.pid == claiming.pid for p in rig._peer_of.values()), [rig, ctl],
              [claiming], "rig_sim tried the claimant's endpoint")
        assert real.wait_for_subscribers(1, 30)
        for i in range(3):
            real.publish(M.GripCommand(normal_force_kpa=3.0, period=i))
        until(lambda: len(got) >= 3, [rig, ctl], [honest, claiming], "the real commands")
        deadline = time.monotonic() + 1.0         # a bound: nothing forged may arrive meanwhile
        while time.monotonic() < deadline:
            rig.spin_once(0.05)
        assert [m.normal_force_kpa for m in got] == [3.0] * 3
        assert len(rig.refused_writers) == 1       # logged once per peer, however many refused
        honest.kill()
        claiming.kill()
        assert "subscribed" not in claiming.communicate()[0], "a reader completed a handshake with the claimant"


def test_an_unknown_key_is_refused_at_zap_and_its_node_is_not_read(tcp):
    """A key in the keystore but not in the permissions file (a node the launch does not name),
    and a key of its own: ZAP refuses both; nothing they publish is read."""
    ctx = zmq.Context()
    intruder_keys = security.node_keys(tcp.store, "intruder")
    with Node("estimator") as est, Node("grip_controller", writers={M.SlipEstimate.TOPIC: ["estimator"]}) as ctl, \
            Node("intruder") as intruder:
        pub = est.create_publisher(M.SlipEstimate)
        got = []
        ctl.create_subscription(M.SlipEstimate, got.append)
        socks = []
        for public, secret in (intruder_keys, zmq.curve_keypair()):
            s = ctx.socket(zmq.SUB)
            s.curve_publickey, s.curve_secretkey = public, secret
            s.curve_serverkey = security.node_keys(tcp.store, "estimator")[0]
            s.setsockopt(zmq.SUBSCRIBE, b"")
            s.connect(est._info.endpoint)
            socks.append(s)
        until(lambda: est.refused_clients >= 2 and ("intruder", os.getpid()) in ctl.refused_writers,
              [est, ctl, intruder], what="ZAP refused both, grip_controller refused the intruder")
        assert "no key for identity intruder" in ctl.refused_writers[("intruder", os.getpid())]
        assert pub.wait_for_subscribers(1, 30)
        pub.publish(M.SlipEstimate(stick_ratio=0.5, valid=True))
        until(lambda: got, [est, ctl, intruder], what="the estimate")
        assert pub.subscriber_count() == 1
        for s in socks:
            assert not s.poll(300), "a client with an unknown key received a message"
            s.close(linger=0)
    ctx.term()


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o660])
def test_key_files_are_private_and_a_readable_one_is_refused(tcp, mode):
    with Node("estimator"):
        pass
    secret = tcp.store / "estimator.key_secret"
    assert secret.stat().st_mode & 0o777 == 0o600 and tcp.store.stat().st_mode & 0o777 == 0o700
    secret.chmod(mode)
    with pytest.raises(security.TransportError, match="chmod 600"):
        Node("estimator")
    code = ("from incipient_slip.graph.runtime import Node, run_node\n"
            "class X(Node):\n"
            "    def __init__(self, **kw):\n"
            "        super().__init__('estimator', **kw)\n"
            "        self.shutdown()\n"
            "raise SystemExit(run_node(X, []))\n")
    done = subprocess.run([sys.executable, "-c", code], env=tcp.env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "chmod 600" in done.stderr


def test_a_keystore_others_can_write_is_refused(tcp):
    tcp.store.chmod(0o770)
    with pytest.raises(security.TransportError, match="chmod 700"):
        Node("estimator")


def test_rotation_cuts_the_old_key_off_and_a_restarted_node_is_read_again(tcp):
    with Node("grip_controller", writers={M.SlipEstimate.TOPIC: ["estimator"]}) as ctl:
        got = []
        ctl.create_subscription(M.SlipEstimate, got.append)
        old = Node("estimator")
        old_keys = old._keys
        pub = old.create_publisher(M.SlipEstimate)
        until(lambda: pub.subscriber_count() >= 1, [ctl, old], what="grip_controller subscribed")
        pub.publish(M.SlipEstimate(stick_ratio=0.1, valid=True))
        until(lambda: len(got) == 1, [ctl, old], what="the first estimate")
        done = subprocess.run([sys.executable, "-m", "incipient_slip.cli", "keys", "rotate", "estimator"],
                              env=tcp.env, capture_output=True, text=True, timeout=60)
        assert done.returncode == 0 and "estimator: " in done.stdout, done.stderr
        new_key = security.node_keys(tcp.store, "estimator")[0]
        assert new_key != old_keys[0]
        assert json.loads((tcp.store / "permissions.json").read_text())["nodes"]["estimator"]["key"] == new_key.decode()
        assert (tcp.store / "estimator.key_secret").stat().st_mode & 0o777 == 0o600
        # grip_controller cuts the connection pinned to the old key; the old process is told
        until(lambda: pub.subscriber_count() == 0 and old._said_rotated, [ctl, old],
              what="the old key cut off")
        pub.publish(M.SlipEstimate(stick_ratio=0.9, valid=True))
        # the restarted node holds the new key and is read again
        new = Node("estimator")
        assert new._keys[0] == new_key
        pub2 = new.create_publisher(M.SlipEstimate)
        until(lambda: pub2.subscriber_count() >= 1, [ctl, old, new], what="grip_controller subscribed anew")
        pub2.publish(M.SlipEstimate(stick_ratio=0.2, valid=True))
        until(lambda: len(got) >= 2, [ctl, old, new], what="the restarted node's estimate")
        assert [m.stick_ratio for m in got] == [0.1, 0.2]
        # ZAP refuses the old key from now on
        ctx = zmq.Context()
        s = ctx.socket(zmq.SUB)
        s.curve_publickey, s.curve_secretkey = old_keys
        s.curve_serverkey = security.node_keys(tcp.store, "grip_controller")[0]
        s.setsockopt(zmq.SUBSCRIBE, b"")
        before = ctl.refused_clients
        s.connect(ctl._info.endpoint)
        until(lambda: ctl.refused_clients > before, [ctl, old, new], what="ZAP refused the old key")
        s.close(linger=0)
        ctx.term()
        old.close()
        new.close()


def test_the_tools_key_is_read_only_unless_force(tcp):
    """rig_sim reads /pzt/command, which no node of the launch writes: the tools' --force key may
    send it, their plain key may not (counted, logged once); `slip topic echo` reads over tcp."""
    with Node("rig_sim", writers=RIG_WRITERS) as rig, \
            Node("slip_topic_pub", identity=security.TOOL_IDENTITY) as plain, \
            Node("slip_topic_pub", identity=security.FORCE_IDENTITY) as forced:
        got = []
        rig.create_subscription(M.PztCommand, got.append)
        pubs = [plain.create_publisher(M.PztCommand), forced.create_publisher(M.PztCommand)]
        until(lambda: all(p.subscriber_count() for p in pubs), [rig, plain, forced], what="rig_sim subscribed to both")
        pubs[0].publish(M.PztCommand(enabled=False))
        pubs[1].publish(M.PztCommand(enabled=True))
        until(lambda: got and rig.refused_messages, [rig, plain, forced], what="one taken, one refused")
        assert [m.enabled for m in got] == [True]
        (name, pid), = rig.refused_writers
        assert f"identity {security.TOOL_IDENTITY}) may not publish" in rig.refused_writers[(name, pid)]
        # slip topic echo joins with the tools' key and reads
        echo = tcp.spawn(["python", "-m", "incipient_slip.cli", "topic", "echo", M.PztCommand.TOPIC, "-n", "1", "--json"], text=True)
        until(lambda: pubs[1].subscriber_count() >= 2, [rig, plain, forced], [echo], what="slip topic echo subscribed")
        pubs[1].publish(M.PztCommand(enabled=True))
        out, err = echo.communicate(timeout=60)
        assert echo.returncode == 0 and json.loads(out)["enabled"] is True, err


def test_slip_topic_pub_says_when_the_tools_key_may_not_publish(tcp):
    for extra, expect in (([], "pass --force"), (["--force"], "(slip-force) may not publish")):
        done = subprocess.run([sys.executable, "-m", "incipient_slip.cli", "topic", "pub", M.SlipEstimate.TOPIC,
                               "{stick_ratio: 0.3, valid: true}", *extra], env=tcp.env,
                              capture_output=True, text=True, timeout=60)
        assert done.returncode == 2 and expect in done.stderr, done.stderr


def test_a_launch_over_tcp_writes_its_permissions_and_its_rig_refuses_a_forger_with_a_stolen_key(tcp):
    """The real stabilize.yaml over tcp, with a forger already running that holds the estimator's
    key and calls itself grip_controller: its 99 kPa commands and its hello (which would let
    rig_sim start before the real grip_controller listens) are refused by key; the run succeeds."""
    forger = _forger(tcp, "estimator")
    launch = tcp.spawn(["python", "-m", "incipient_slip.graph.launch", "stabilize.yaml", "steps:=12",
                        "quiet:=true", f"summary:={tcp.dir}/summary.json"], text=True)
    out, err = launch.communicate(timeout=240)
    forger.kill()
    assert launch.returncode == 0, err[-3000:]
    assert (f"[rig_sim] WARNING: messages from grip_controller (pid {forger.pid}) refused: it sent "
            f"/grip/command, which its key (identity estimator) may not publish") in err
    assert "[rig_sim] WARNING: a subscriber with the key of estimator said it is grip_controller" in err
    written = json.loads((tcp.store / "permissions.json").read_text())
    assert written["written_by"].startswith("launch ") and written["nodes"]["rig_sim"]["subscribe"] == [
        "/actuator/command", "/grip/command", "/pzt/command", "/run/event"]
    for name in ("rig_sim", "estimator", "grip_controller", "supervisor"):
        assert (tcp.store / f"{name}.key_secret").stat().st_mode & 0o777 == 0o600
    assert json.loads((tcp.dir / "summary.json").read_text())["outcome"] == "success"
