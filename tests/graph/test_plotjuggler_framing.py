"""What PlotJuggler shows of our topics, by a Python transcription of its code (PlotJuggler
commit ddcbd05): the ZMQ Subscriber's receive loop (plotjuggler_plugins/DataStreamZMQ/
datastream_zmq.cpp, `receiveLoop`) and the MessagePack/JSON flattening
(plotjuggler_app/nlohmann_parsers.cpp, `parseMessageImpl`), run against a live node."""
from __future__ import annotations

import json

import msgpack
import numpy as np
import zmq

from incipient_slip.graph import discovery
from incipient_slip.graph.bag_export import to_export_json
from incipient_slip.messages import ObjectPose, SlipEstimate


def flatten(prefix: str, value, out: dict) -> None:
    """parseMessageImpl's `flatten`: objects -> prefix/key, arrays -> prefix[i]; only numbers
    and booleans become series (strings, nil and msgpack bin are skipped)."""
    if isinstance(value, dict):
        for key, item in value.items():
            flatten(f"{prefix}/{key}", item, out)
    elif isinstance(value, list):
        for i, item in enumerate(value):
            flatten(f"{prefix}[{i}]", item, out)
    elif isinstance(value, (bool, int, float)):
        out[prefix] = float(value)


def receive_like_plotjuggler(sock: zmq.Socket) -> tuple[str, bytes]:
    """receiveLoop: first part = topic (when more parts follow), next = body, a third = stamp."""
    first = sock.recv()
    topic, body = "", first
    if sock.getsockopt(zmq.RCVMORE):
        topic = first.decode("latin-1")          # std::string of all its bytes, NUL included
        body = sock.recv()
    assert not sock.getsockopt(zmq.RCVMORE)     # no third part: PlotJuggler uses receive time
    return topic, body


def test_plotjuggler_zmq_subscriber_reads_our_frames_and_plots_scalars_but_not_bin_arrays(graph, probe):
    estimates = probe.node.create_publisher(SlipEstimate)
    poses = probe.node.create_publisher(ObjectPose)
    me = next(i for i in discovery.scan(graph.dir) if i.name == "probe")
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 5000)
    sock.connect(me.endpoint)                                # PlotJuggler: "ipc://" + path
    for topic_filter in ("/slip/estimate", "/object/pose"):   # its topic filter box, as typed
        sock.setsockopt(zmq.SUBSCRIBE, topic_filter.encode())
    try:
        probe.until(lambda: estimates.subscriber_count() >= 1 and poses.subscriber_count() >= 1,
                    what="PlotJuggler's SUB subscribed")
        estimates.publish(SlipEstimate(stick_ratio=0.42, valid=True, period=3))
        poses.publish(ObjectPose(position_mm=np.array([0.5, 1.25, -2.0]), orientation_xyzw=np.array([0.0, 0.0, 0.0, 1.0])))
        series = {}
        for _ in range(2):
            topic, body = receive_like_plotjuggler(sock)
            flatten(topic, msgpack.unpackb(body, raw=False), series)
    finally:
        sock.close()
    assert series["/slip/estimate\0/stick_ratio"] == 0.42
    assert series["/slip/estimate\0/valid"] == 1.0 and series["/slip/estimate\0/period"] == 3.0
    assert "/slip/estimate\0/method" not in series                  # strings do not plot
    assert series["/object/pose\0/tracking_valid"] == 1.0
    # the array's map plots its shape, never its data (msgpack bin): y is not there
    assert series["/object/pose\0/position_mm/shape[0]"] == 3.0
    assert not [name for name in series if "position_mm/data" in name]


def test_the_foxglove_export_json_plots_arrays_in_plotjuggler():
    pose = ObjectPose(position_mm=np.array([0.5, 1.25, -2.0]), orientation_xyzw=np.array([0.0, 0.0, 0.0, 1.0]), stamp_ns=10**9, seq=1)
    series = {}
    flatten("/object/pose", json.loads(json.dumps(to_export_json(pose))), series)
    assert series["/object/pose/position_mm[1]"] == 1.25                # y
