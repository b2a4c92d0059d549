"""mocap_bridge: the object's rigid body from OptiTrack Motive (NatNet) as /object/pose.

    python -m incipient_slip.nodes.mocap_bridge server_address:=192.168.1.10 body_id:=1

Publishes one `ObjectPose` per Motive frame that tracks the body, in the rig frame: Motive's
frame turned by the proper rotation (`RAIL_ROTATIONS`) that takes the rail axis (`rail_axis`, a
Motive axis) to +y, the paper's travel; position in mm and orientation (x, y, z, w) rotated
together, world and body axes alike (q' = r q r*: a body Motive reports at identity is at
identity, a turn about the rail is a turn about y), so the frame stays right-handed (y: identity; -y: 180 deg about z; x: +90 deg about z,
Motive's y becomes -x; -x: -90 deg about z; z: -90 deg about x, Motive's y becomes -z; -z:
+90 deg about x). `stamp_ns` is the frame's mid-exposure time on this host's
clock: the receive time less the latency Motive's own clock stamps report (NatNet >= 3.0; the
receive time before). A frame where the body is untracked, missing or non-finite is missing
data: nothing is published for it (never a zero pose), it is counted and warned about.

The NatNet client (`devices.natnet`) parses by the server's version, counts and drops bad
packets, and reconnects with back-off (at start, capped at half the time left to
`startup_timeout_s`, so it keeps trying until the deadline); its notices become log lines: NO_DATA names the Motive
settings to check, a NatNet version change is an alarm. With no server info within
`startup_timeout_s` the node exits 2 with one line naming the address (a missing device).
"""
from __future__ import annotations

import socket
import time

import numpy as np

from incipient_slip.devices import natnet as nn
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.devices.rig_config import apply_rig_config
from incipient_slip.messages import ObjectPose

EXIT_NO_DEVICE = 2
_H = float(np.sqrt(0.5))
# rail axis -> (rotation matrix, the same rotation as a quaternion x, y, z, w): each takes
# the rail's unit vector to +y and is proper (det +1).
RAIL_ROTATIONS = {
    "y": (np.eye(3), (0.0, 0.0, 0.0, 1.0)),
    "-y": (np.array([[-1, 0, 0], [0, -1, 0], [0, 0, 1]], float), (0.0, 0.0, 1.0, 0.0)),
    "x": (np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], float), (0.0, 0.0, _H, _H)),
    "-x": (np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], float), (0.0, 0.0, -_H, _H)),
    "z": (np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float), (-_H, 0.0, 0.0, _H)),
    "-z": (np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float), (_H, 0.0, 0.0, _H)),
}
RAIL_AXES = tuple(RAIL_ROTATIONS)


def quaternion_product(a, b) -> np.ndarray:
    """a * b for quaternions (x, y, z, w): the rotation b, then a."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def pose_from_frame(frame: nn.Frame, body_id: int, rail_axis: str, recv_ns: int,
                    clock_hz: int = 0) -> tuple[ObjectPose | None, str]:
    """(ObjectPose, "") for the body in `frame`, or (None, why) when the frame has no usable
    pose of it: "missing", "untracked" or "non-finite"."""
    body = frame.rigid_body(body_id)
    if body is None:
        return None, "missing"
    if not body.tracking_valid:
        return None, "untracked"
    position = np.asarray(body.position_m, dtype=float) * 1000.0
    orientation = np.asarray(body.orientation_xyzw, dtype=float)
    if not (np.isfinite(position).all() and np.isfinite(orientation).all()):
        return None, "non-finite"
    rotation, q_rotation = RAIL_ROTATIONS[rail_axis]
    position = rotation @ position                     # the rail axis becomes +y
    conjugate = (-q_rotation[0], -q_rotation[1], -q_rotation[2], q_rotation[3])
    orientation = quaternion_product(quaternion_product(q_rotation, orientation), conjugate)
    latency_ns = 0
    if clock_hz > 0 and frame.transmit_ticks >= frame.mid_exposure_ticks:
        latency_ns = (frame.transmit_ticks - frame.mid_exposure_ticks) * 1_000_000_000 // clock_hz
    return ObjectPose(position_mm=position, orientation_xyzw=orientation, tracking_valid=True,
                      body_id=max(body_id, 0), stamp_ns=max(recv_ns - latency_ns, 1)), ""


def _address(name: str, value: str) -> str:
    try:
        socket.inet_aton(value)
    except OSError:
        raise ParamError(f"node 'mocap_bridge': parameter {name}:={value!r} is not an IPv4 address") from None
    return value


class MocapBridge(Node):
    """Streams the object's rigid body from Motive over NatNet to /object/pose."""

    INPUTS: dict = {}
    OUTPUTS = {ObjectPose.TOPIC: ObjectPose}
    PARAMS = {
        "rig_config": Param("", help="config/rig.yaml: unset parameters from its natnet section"),
        "server_address": Param("127.0.0.1", help="Motive's address (its Local Interface)"),
        "local_address": Param("127.0.0.1", help="this computer's address on Motive's network"),
        "command_port": Param(nn.DEFAULT_COMMAND_PORT, lo=1, hi=65535, help="Motive command port"),
        "data_port": Param(nn.DEFAULT_DATA_PORT, lo=1, hi=65535, help="Motive data port"),
        "multicast": Param(False, choices=(False, True), help="Transmission Type multicast (else unicast)"),
        "multicast_address": Param(nn.DEFAULT_MULTICAST_ADDRESS, help="Motive's multicast group"),
        "body_id": Param(1, lo=0, hi=2**31 - 1, help="streaming id of the object's rigid body"),
        "rail_axis": Param("y", choices=RAIL_AXES, help="Motive axis along the rail (rotated to +y)"),
        "no_data_s": Param(1.0, lo=0.05, hi=60.0, help="no frame this long: NO_DATA, reconnect"),
        "connect_timeout_s": Param(1.0, lo=0.05, hi=60.0, help="first connect retry; doubles up to 8 s"),
        "startup_timeout_s": Param(5.0, lo=0.0, hi=3600.0, help="exit 2 without server info by then (0: wait)"),
        "poll_s": Param(0.002, lo=0.0005, hi=0.1, help="how often the UDP sockets are read"),
    }

    def __init__(self, **kwargs):
        super().__init__("mocap_bridge", **kwargs)
        apply_rig_config(self, "natnet", kwargs.get("params"))
        p = self.param
        self.body_id, self.rail_axis = p("body_id"), p("rail_axis")
        startup_s = p("startup_timeout_s")
        self._deadline = time.monotonic() + startup_s if startup_s > 0 else None
        self.client = nn.NatNetClient(
            _address("server_address", p("server_address")),
            local_address=_address("local_address", p("local_address")),
            command_port=p("command_port"), data_port=p("data_port"), multicast=p("multicast"),
            multicast_address=_address("multicast_address", p("multicast_address")),
            no_data_s=p("no_data_s"), connect_timeout_s=p("connect_timeout_s"),
            connect_by=self._deadline)       # attempts go on until the deadline, not 8 s before
        opened_by = time.monotonic() + startup_s
        while True:      # the network (or its address) may come up a little after the node
            try:
                self.client.open()
                break
            except OSError as exc:
                if time.monotonic() >= opened_by:
                    raise ParamError(str(exc)) from None
                time.sleep(0.2)
        self.on_shutdown(self._close)
        self.skipped = {"missing": 0, "untracked": 0, "non-finite": 0}
        self.published = 0
        self.pose_pub = self.create_publisher(ObjectPose)
        self.create_timer(p("poll_s"), self.poll)

    def poll(self):
        frames, notices = self.client.poll()
        recv_ns = time.time_ns()
        for notice in notices:
            if notice.kind == "version_change":
                self.warn(f"ALARM: {notice.text}")
            elif notice.kind == "no_data":
                self.warn(f"NO_DATA: {notice.text}", throttle_s=5.0, key="no_data")
            else:
                self.log(notice.text)
        info = self.client.server_info
        for frame in frames:
            pose, why = pose_from_frame(frame, self.body_id, self.rail_axis, recv_ns,
                                        info.clock_hz if info else 0)
            if pose is None:
                self.skipped[why] += 1
                present = [b.body_id for b in frame.rigid_bodies]
                self.warn(f"frame {frame.frame_number}: rigid body {self.body_id} {why} "
                          f"(bodies in the stream: {present}); no pose published",
                          throttle_s=2.0, key=why)
                continue
            self.pose_pub.publish(pose)
            self.published += 1
        if self._deadline is not None:
            if info is not None:
                self._deadline = None
            elif time.monotonic() > self._deadline:
                self.log(f"mocap_bridge: no NatNet server at {self.client.server[0]}:"
                         f"{self.client.server[1]} (no server info in "
                         f"{self.param('startup_timeout_s'):g} s): is Motive running with "
                         f"streaming on, and is server_address its Local Interface?")
                self.shutdown("no motion-capture server", EXIT_NO_DEVICE)

    def _close(self):
        stats = dict(self.client.stats)
        self.log(f"published {self.published} poses; skipped {self.skipped}; NatNet {stats}")
        self.client.close()


def main(argv=None):
    return run_node(MocapBridge, argv)


if __name__ == "__main__":
    raise SystemExit(main())
