"""The NatNet parser on golden packets of every supported version, on packets of the wrong
version, and under fuzzing: a bad packet is a NatNetError with a reason, never another exception."""
from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given, settings, strategies as st

from incipient_slip.devices import natnet as nn
from natnet_golden import BODY_1, BODY_7, EXPECTED, golden_frame, golden_server_info

VERSIONS = nn.VERSIONS


def close(a, b):
    return all(math.isclose(x, y, rel_tol=1e-6, abs_tol=1e-7) for x, y in zip(a, b))


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: f"{v[0]}.{v[1]}")
def test_golden_frame_parses_to_its_rigid_bodies_and_suffix(version):
    frame = nn.parse_frame(golden_frame(version), version)
    assert frame.frame_number == EXPECTED["frame_number"]
    assert [b.body_id for b in frame.rigid_bodies] == [1, 7]
    one, seven = frame.rigid_bodies
    assert close(one.position_m, BODY_1["position_m"]) and close(one.orientation_xyzw, BODY_1["orientation_xyzw"])
    assert one.tracking_valid and not seven.tracking_valid
    assert math.isclose(one.mean_error_m, 0.0005, rel_tol=1e-6)
    assert (frame.timecode, frame.timecode_subframe, frame.timestamp_s, frame.params) == (
        EXPECTED["timecode"], EXPECTED["timecode_subframe"], EXPECTED["timestamp_s"], EXPECTED["params"])
    if version[0] >= 3:
        assert (frame.mid_exposure_ticks, frame.data_received_ticks, frame.transmit_ticks) == (1000, 2000, 3000)
    if version >= (4, 1):
        assert (frame.precision_s, frame.precision_fraction) == (55, 66)
    assert frame.rigid_body(7) is seven and frame.rigid_body(2) is None


@pytest.mark.parametrize("precision", [False, True])
def test_natnet_4_0_suffix_is_read_with_or_without_the_precision_timestamp(precision):
    frame = nn.parse_frame(golden_frame((4, 0), precision_in_4_0=precision), (4, 0))
    assert (frame.precision_s, frame.precision_fraction) == ((55, 66) if precision else (0, 0))
    assert frame.params == EXPECTED["params"]


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: f"{v[0]}.{v[1]}")
def test_emulator_packer_writes_the_golden_bytes(version):
    """pack_frame (what the emulator sends) byte for byte against the golden writer."""
    frame = nn.Frame(rigid_bodies=(nn.RigidBody(**BODY_1), nn.RigidBody(**BODY_7)), **EXPECTED)
    message_id, payload = nn.split_packet(nn.pack_frame(frame, version))
    assert message_id == nn.NAT_FRAMEOFDATA
    assert bytes(payload) == golden_frame(version, populated=False)


@pytest.mark.parametrize("sent", VERSIONS, ids=lambda v: f"{v[0]}.{v[1]}")
@pytest.mark.parametrize("read_as", VERSIONS, ids=lambda v: f"as{v[0]}.{v[1]}")
def test_frame_read_as_another_version_is_refused_or_identical(sent, read_as):
    """A version mismatch never yields a different frame: the layouts that differ are refused."""
    payload = golden_frame(sent)
    try:
        frame = nn.parse_frame(payload, read_as)
    except nn.NatNetError:
        assert sent != read_as
        return
    reference = nn.parse_frame(payload, sent)
    assert [(b.body_id, b.position_m, b.tracking_valid) for b in frame.rigid_bodies] == \
           [(b.body_id, b.position_m, b.tracking_valid) for b in reference.rigid_bodies]


def test_rigid_body_block_must_match_its_byte_count():
    payload = bytearray(golden_frame((4, 1)))
    # marker sets block: count(4) + bytes(4) + 4 + 4 + 24 bytes; then legacy: 4 + 4 + 12
    offset = 4 + 8 + (4 + 4 + 24) + 8 + 12 + 4     # the rigid bodies' byte count
    (size,) = struct.unpack_from("<i", payload, offset)
    struct.pack_into("<i", payload, offset, size - 2)
    with pytest.raises(nn.NatNetError) as err:
        nn.parse_frame(bytes(payload), (4, 1))
    assert err.value.reason == "count"


def test_suffix_with_extra_bytes_is_refused():
    with pytest.raises(nn.NatNetError) as err:
        nn.parse_frame(golden_frame((3, 1)) + b"\0\0", (3, 1))
    assert err.value.reason == "suffix"


@pytest.mark.parametrize("version", VERSIONS, ids=lambda v: f"{v[0]}.{v[1]}")
def test_server_info_parses_name_versions_and_stream_setup(version):
    info = nn.parse_server_info(golden_server_info(version))
    assert info.app_name == "Motive" and info.app_version == (3, 1, 0, 0)
    assert info.version == version
    if version[0] >= 3:
        assert (info.clock_hz, info.data_port, info.multicast, info.multicast_address) == (
            10_000_000, 1511, True, "239.255.42.99")
    assert nn.parse_server_info(nn.split_packet(nn.pack_server_info(info))[1]) == info


def test_server_info_truncated_or_trailing_is_refused():
    payload = golden_server_info((4, 1))
    with pytest.raises(nn.NatNetError, match="truncated"):
        nn.parse_server_info(payload[:-1])
    with pytest.raises(nn.NatNetError, match="trailing"):
        nn.parse_server_info(payload + b"\0")


def test_connect_packets_carry_the_requested_version_or_the_legacy_ping():
    message_id, payload = nn.split_packet(nn.pack_connect((4, 1, 0, 0)))
    assert message_id == nn.NAT_CONNECT and len(payload) == 271
    assert bytes(payload[:4]) == b"Ping" and nn.connect_version(payload) == (4, 1, 0, 0)
    message_id, payload = nn.split_packet(nn.pack_legacy_ping())
    assert bytes(payload) == b"Ping\0" and nn.connect_version(payload) is None


def test_header_length_must_match_the_datagram():
    packet = nn.pack_packet(nn.NAT_FRAMEOFDATA, golden_frame((4, 1)))
    with pytest.raises(nn.NatNetError, match="length"):
        nn.split_packet(packet[:-1])
    with pytest.raises(nn.NatNetError, match="short"):
        nn.split_packet(packet[:3])


# --- fuzz -----------------------------------------------------------------------------------

versions = st.sampled_from(VERSIONS)


@settings(max_examples=300, deadline=None)
@given(versions, st.data())
def test_any_truncation_of_a_frame_is_a_natnet_error(version, data):
    payload = golden_frame(version)
    cut = data.draw(st.integers(0, len(payload) - 1))
    with pytest.raises(nn.NatNetError):
        nn.parse_frame(payload[:cut], version)


@settings(max_examples=500, deadline=None)
@given(versions, st.data())
def test_mutated_frames_parse_or_raise_natnet_error_only(version, data):
    payload = bytearray(golden_frame(version))
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    try:
        frame = nn.parse_frame(bytes(payload), version)
    except nn.NatNetError as exc:
        assert exc.reason in ("truncated", "count", "suffix")
        return
    assert isinstance(frame, nn.Frame)


def _accounted(stats) -> int:
    return (stats["dropped"] + stats["frames"] + stats["server_info"]
            + sum(v for k, v in stats.items() if k.startswith("message:")))


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600), versions)
def test_every_datagram_is_exactly_one_counted_outcome_never_an_exception(blob, version):
    client = nn.NatNetClient(command_port=1)      # never opened: _handle is pure
    client.server_info = nn.ServerInfo("x", (1, 0, 0, 0), version + (0, 0))
    for i, data in enumerate((blob, nn.pack_packet(nn.NAT_FRAMEOFDATA, blob[:nn.MAX_PAYLOAD]),
                              nn.pack_packet(nn.NAT_SERVERINFO, blob[:nn.MAX_PAYLOAD]))):
        client._handle(data, ("127.0.0.1", 1))
        assert _accounted(client.stats) == i + 1


def test_frame_before_server_info_is_dropped_unparsed():
    client = nn.NatNetClient(command_port=1)
    client._handle(nn.pack_packet(nn.NAT_FRAMEOFDATA, golden_frame((4, 1))), ("127.0.0.1", 1))
    assert client.stats["dropped:before_server_info"] == 1 and client.stats["frames"] == 0


def test_frames_from_another_host_are_dropped_in_unicast():
    client = nn.NatNetClient("127.0.0.1", command_port=1)
    client.server_info = nn.ServerInfo("x", (1, 0, 0, 0), (4, 1, 0, 0))
    client._handle(nn.pack_packet(nn.NAT_FRAMEOFDATA, golden_frame((4, 1))), ("10.0.0.9", 1))
    assert client.stats["dropped:foreign_source"] == 1


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 400), min_size=1, max_size=80))
def test_frames_leave_the_client_in_increasing_order_and_every_arrival_is_accounted(numbers):
    """Any arrival order (gaps, duplicates, late frames): out in increasing frame order except
    where the stream restarted (a jump back of RESTART_JUMP_FRAMES or more, counted), and
    frames out + duplicates + late ones = arrivals."""
    client = nn.NatNetClient(command_port=1)
    client.server_info = nn.ServerInfo("x", (1, 0, 0, 0), (4, 1, 0, 0))
    body = nn.RigidBody(1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    out = []
    for number in numbers:
        frame = client._handle(nn.pack_frame(nn.Frame(number, (body,)), (4, 1)), ("127.0.0.1", 1))
        if frame is not None:
            out.append(frame.frame_number)
    s = client.stats
    backs = [i for i in range(1, len(out)) if out[i] <= out[i - 1]]
    assert len(backs) == s["stream_restarts"]
    assert all(out[i - 1] - out[i] >= nn.RESTART_JUMP_FRAMES for i in backs)
    assert len(out) + s["dropped:duplicate"] + s["dropped:reordered"] == len(numbers)
