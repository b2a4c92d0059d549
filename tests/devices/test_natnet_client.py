"""The NatNet client against the emulated Motive on loopback (never ports 1510/1511): connect
and fallback, unicast/multicast, keepalives, and every emulator fault with the behaviour the
client owes it. Tests wait for conditions (with a hard deadline), never for fixed times."""
from __future__ import annotations

import math
import time

import pytest

from incipient_slip.devices import natnet as nn
from incipient_slip.devices.natnet_emulator import NatNetEmulator, free_udp_port

pytestmark = pytest.mark.timeout(60)




class Session:
    """A client polled in a loop, keeping every frame and notice it returned."""

    def __init__(self, client):
        self.client, self.frames, self.notices = client, [], []

    def until(self, predicate, timeout_s=10.0):
        deadline = time.monotonic() + timeout_s
        while not predicate():
            assert time.monotonic() < deadline, f"timed out; stats {dict(self.client.stats)}"
            frames, notices = self.client.poll()
            self.frames += frames
            self.notices += notices
            time.sleep(0.002)

    def kinds(self):
        return [n.kind for n in self.notices]


@pytest.fixture
def rig():
    """start(version, **emulator_kw) -> (emulator, Session); everything closed at teardown."""
    opened = []

    def start(version=(4, 1), client_kw=None, **kw):
        data_port = free_udp_port()
        emulator = NatNetEmulator(version, data_port=data_port, **kw).start()
        client = nn.NatNetClient(command_port=emulator.command_port, data_port=data_port,
                                 multicast=kw.get("multicast", False), **(client_kw or {})).open()
        opened.append((emulator, client))
        return emulator, Session(client)

    yield start
    for emulator, client in opened:
        client.close()
        emulator.stop()


@pytest.mark.parametrize("version", nn.VERSIONS, ids=lambda v: f"{v[0]}.{v[1]}")
def test_unicast_stream_of_each_version_delivers_the_body_pose(rig, version):
    emulator, s = rig(version)
    emulator.set_pose((0.01, 0.0235, -0.002), (0.0, 0.0, 0.0, 1.0))
    s.until(lambda: len(s.frames) >= 10)
    assert s.client.version == version and s.kinds()[0] == "connected"
    body = s.frames[-1].rigid_body(1)
    assert body.tracking_valid
    assert all(math.isclose(a, b, rel_tol=1e-6) for a, b in zip(body.position_m, (0.01, 0.0235, -0.002)))
    numbers = [f.frame_number for f in s.frames]
    assert numbers == sorted(numbers) and s.client.stats["dropped"] == 0


def test_multicast_stream_is_received_on_the_data_port(rig):
    emulator, s = rig((4, 2), multicast=True)
    s.until(lambda: len(s.frames) >= 10)
    assert s.client.stats["keepalives"] == 0        # keepalives are for unicast only


def test_unicast_frames_sent_to_the_data_port_are_received_too(rig):
    emulator, s = rig((3, 1), unicast_to_data_port=True)
    s.until(lambda: len(s.frames) >= 10)


def test_unicast_client_sends_keepalives(rig):
    emulator, s = rig((4, 1), client_kw={"keepalive_s": 0.05})
    s.until(lambda: emulator.stats[f"command:{nn.NAT_KEEPALIVE}"] >= 3)


def test_legacy_ping_reaches_a_server_that_ignores_the_4_1_connect_and_nothing_is_parsed_before(rig):
    """Multicast frames arrive before the server info: dropped unparsed, then the legacy ping
    connects and the same stream parses."""
    emulator, s = rig((2, 10), multicast=True, legacy_connect_only=True,
                      client_kw={"connect_timeout_s": 0.2})
    s.until(lambda: len(s.frames) >= 5)
    assert s.client.stats["dropped:before_server_info"] >= 1
    assert s.client.stats["connects"] >= 1 and s.client.stats["legacy_pings"] >= 1
    assert s.client.version == (2, 10)


def test_silent_stop_raises_no_data_naming_motive_settings_then_resumes(rig):
    emulator, s = rig((4, 1), client_kw={"no_data_s": 0.3, "connect_timeout_s": 0.1})
    s.until(lambda: len(s.frames) >= 5)
    emulator.silent_stop = True
    s.until(lambda: "no_data" in s.kinds())
    text = next(n.text for n in s.notices if n.kind == "no_data")
    assert "Broadcast Frame Data" in text and "Local Interface" in text and "multicast" in text
    assert s.client.status == "NO_DATA"
    reconnects = s.client.stats["connects"] + s.client.stats["legacy_pings"]
    s.until(lambda: s.client.stats["connects"] + s.client.stats["legacy_pings"] >= reconnects + 2)
    emulator.silent_stop = False
    n = len(s.frames)
    s.until(lambda: len(s.frames) >= n + 5)
    assert "data_resumed" in s.kinds() and s.client.status == "STREAMING"


def test_tracking_lost_frames_say_so(rig):
    emulator, s = rig((4, 1))
    s.until(lambda: len(s.frames) >= 3)
    emulator.tracking_lost = True
    s.until(lambda: not s.frames[-1].rigid_body(1).tracking_valid)


def test_nan_pose_arrives_as_nan_for_the_node_to_refuse(rig):
    emulator, s = rig((3, 1))
    s.until(lambda: len(s.frames) >= 3)
    emulator.nan_pose = True
    s.until(lambda: math.isnan(s.frames[-1].rigid_body(1).position_m[0]))


def test_frame_gap_is_counted_and_the_stream_goes_on(rig):
    emulator, s = rig((4, 1))
    s.until(lambda: len(s.frames) >= 3)
    emulator.inject("gap", 2)
    s.until(lambda: s.client.stats["missed_frames"] >= 2)
    assert s.client.stats["gaps"] >= 1 and s.client.stats["dropped"] == 0


def test_duplicate_frame_is_dropped(rig):
    emulator, s = rig((4, 1))
    s.until(lambda: len(s.frames) >= 3)
    emulator.inject("duplicate")
    s.until(lambda: s.client.stats["dropped:duplicate"] == 1)
    numbers = [f.frame_number for f in s.frames]
    assert len(numbers) == len(set(numbers))


def test_late_frame_is_dropped_so_poses_never_go_back_in_time(rig):
    emulator, s = rig((4, 1))
    s.until(lambda: len(s.frames) >= 3)
    emulator.inject("reorder")
    s.until(lambda: s.client.stats["dropped:reordered"] == 1)
    numbers = [f.frame_number for f in s.frames]
    assert numbers == sorted(numbers)


def test_truncated_datagram_is_a_counted_drop(rig):
    emulator, s = rig((4, 0))
    s.until(lambda: len(s.frames) >= 3)
    emulator.inject("truncate", 3)
    s.until(lambda: s.client.stats["dropped:length"] == 3)
    n = len(s.frames)
    s.until(lambda: len(s.frames) >= n + 3)


@pytest.mark.parametrize("multicast", [False, True], ids=["unicast", "multicast"])
def test_restart_with_another_version_is_an_alarm_and_parsing_follows(rig, multicast):
    emulator, s = rig((4, 1), multicast=multicast,
                      client_kw={"no_data_s": 0.3, "connect_timeout_s": 0.1})
    s.until(lambda: len(s.frames) >= 3)
    emulator.restart((3, 1))
    s.until(lambda: "version_change" in s.kinds())
    assert "4.1.0.0 to 3.1.0.0" in next(n.text for n in s.notices if n.kind == "version_change")
    n = len(s.frames)
    s.until(lambda: len(s.frames) >= n + 5)
    assert s.client.version == (3, 1) and s.client.stats["version_changes"] == 1


class FakeClock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def attempt_times(client, clock, until_s, step_s=0.01):
    """The clock times at which the client sent a connect or legacy ping, stepping to until_s."""
    times, sent = [], 0
    while clock.t < until_s:
        client.poll()
        now_sent = client.stats["connects"] + client.stats["legacy_pings"]
        times += [clock.t] * (now_sent - sent)
        sent = now_sent
        clock.t = round(clock.t + step_s, 6)
    return times


def test_start_up_attempts_go_on_until_the_deadline_not_8_s_before():
    clock = FakeClock()
    port = free_udp_port()          # nobody answers there
    client = nn.NatNetClient(command_port=port, data_port=free_udp_port(), connect_by=20.0,
                             clock=clock).open()
    try:
        times = attempt_times(client, clock, 20.0)
    finally:
        client.close()
    assert times[:4] == [0.0, 1.0, 2.0, 4.0]                   # the back-off as before
    gaps_to_deadline = [20.0 - t for t in times]
    assert min(gaps_to_deadline) <= 0.1                        # was 6 s: the last try at 14 s
    for before, after in zip(times, times[1:]):               # never a gap longer than half the rest
        assert after - before <= max((20.0 - before) / 2, nn.MIN_CONNECT_GAP_S) + 0.011


def test_without_a_deadline_the_back_off_reaches_its_cap():
    clock = FakeClock()
    client = nn.NatNetClient(command_port=free_udp_port(), data_port=free_udp_port(), clock=clock).open()
    try:
        times = attempt_times(client, clock, 40.0)
    finally:
        client.close()
    assert times[:8] == [0.0, 1.0, 2.0, 4.0, 6.0, 10.0, 14.0, 22.0]
