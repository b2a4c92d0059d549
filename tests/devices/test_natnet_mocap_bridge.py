"""mocap_bridge on the emulated Motive: /object/pose in mm along the rail, stamped at exposure,
never a zero or NaN pose for an untracked or broken frame, exit 2 when no server answers."""
from __future__ import annotations


import numpy as np
import pytest

from incipient_slip.devices import natnet as nn
from incipient_slip.devices.natnet_emulator import NatNetEmulator, free_udp_port
from incipient_slip.graph.runtime import Node
from incipient_slip.messages import ObjectPose
from incipient_slip.nodes.mocap_bridge import MocapBridge, pose_from_frame
from waiting import spin_until

pytestmark = pytest.mark.timeout(60)




def frame_with(body: nn.RigidBody, **kw) -> nn.Frame:
    return nn.Frame(frame_number=1, rigid_bodies=(body,), **kw)


@pytest.mark.parametrize("axis, expected", [
    ("y", [10.0, 23.5, -2.0]), ("-y", [-10.0, -23.5, -2.0]), ("x", [-23.5, 10.0, -2.0]),
    ("-x", [23.5, -10.0, -2.0]), ("z", [10.0, -2.0, -23.5]), ("-z", [10.0, 2.0, 23.5])])
def test_rail_axis_is_rotated_to_y_in_mm(axis, expected):
    body = nn.RigidBody(1, (0.010, 0.0235, -0.002), (0.0, 0.0, 0.0, 1.0))
    pose, why = pose_from_frame(frame_with(body), 1, axis, recv_ns=10**18)
    assert why == "" and np.allclose(pose.position_mm, expected)


def matrix_of(q):
    """The rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def published(axis, position_m, orientation_xyzw):
    pose, _ = pose_from_frame(frame_with(nn.RigidBody(1, position_m, orientation_xyzw)), 1, axis, recv_ns=1)
    return pose.position_mm / 1000.0, np.asarray(pose.orientation_xyzw)


@pytest.mark.parametrize("axis", ["y", "-y", "x", "-x", "z", "-z"])
def test_rail_axis_turns_position_and_orientation_together_by_a_proper_rotation(axis):
    # the position map, read off the bridge: where Motive's unit vectors go
    R = np.column_stack([published(axis, tuple(e), (0.0, 0.0, 0.0, 1.0))[0] for e in np.eye(3)])
    rail = np.zeros(3)
    rail["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
    assert np.allclose(R @ rail, [0.0, 1.0, 0.0]) and np.isclose(np.linalg.det(R), 1.0)   # right-handed
    # a known pose: 90 deg about the rail in Motive is 90 deg about +y on the rig
    s = np.sqrt(0.5)
    _, q = published(axis, (0.0, 0.0, 0.0), (*(s * rail), s))
    assert np.allclose(matrix_of(q), matrix_of((0.0, s, 0.0, s)))
    # any pose: a point fixed on the body lands where the rotated Motive point lands (the
    # body's axes are turned as the world's are)
    p = np.array([0.010, 0.0235, -0.002])
    q_motive = np.array([0.1, -0.3, 0.5, 0.8]) / np.linalg.norm([0.1, -0.3, 0.5, 0.8])
    p_rig, q_rig = published(axis, tuple(p), tuple(q_motive))
    marker = np.array([0.03, -0.01, 0.02])            # in the body's frame, on Motive's axes
    assert np.allclose(p_rig + matrix_of(q_rig) @ (R @ marker), R @ (p + matrix_of(q_motive) @ marker))


def test_stamp_is_receive_time_less_motive_reported_latency():
    body = nn.RigidBody(1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    frame = frame_with(body, mid_exposure_ticks=1_000_000, transmit_ticks=1_040_000)
    pose, _ = pose_from_frame(frame, 1, "y", recv_ns=10**18, clock_hz=10_000_000)
    assert pose.stamp_ns == 10**18 - 4_000_000


@pytest.mark.parametrize("body, why", [
    (nn.RigidBody(1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), tracking_valid=False), "untracked"),
    (nn.RigidBody(1, (float("nan"), 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), "non-finite"),
    (nn.RigidBody(2, (0.1, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)), "missing"),
])
def test_unusable_body_gives_no_pose_and_says_why(body, why):
    assert pose_from_frame(frame_with(body), 1, "y", recv_ns=1) == (None, why)


class Probe(Node):
    def __init__(self, graph_dir):
        super().__init__("probe", graph_dir=graph_dir, heartbeat_s=0)
        self.poses: list[ObjectPose] = []
        self.create_subscription(ObjectPose, self.poses.append)


def spin_nodes_until(nodes, predicate, timeout_s=15.0):
    spin_until(lambda: [node.spin_once(0.002) for node in nodes], predicate, timeout_s)


def test_bridge_publishes_tracked_poses_only_and_alarms_on_version_change(graph):
    data_port = free_udp_port()
    with NatNetEmulator((4, 1), data_port=data_port) as emulator:
        emulator.set_pose((0.010, 0.0235, -0.002))
        bridge = MocapBridge(params={"command_port": emulator.command_port, "data_port": data_port,
                                     "no_data_s": 0.3, "connect_timeout_s": 0.1},
                             graph_dir=graph.dir, heartbeat_s=0)
        probe = Probe(graph.dir)
        nodes = (bridge, probe)
        try:
            spin_nodes_until(nodes, lambda: bridge.pose_pub.subscriber_count() >= 1)
            spin_nodes_until(nodes, lambda: len(probe.poses) >= 5)
            assert np.allclose(probe.poses[-1].position_mm, [10.0, 23.5, -2.0], atol=1e-4)
            emulator.tracking_lost = True
            spin_nodes_until(nodes, lambda: bridge.skipped["untracked"] >= 5)
            emulator.tracking_lost, emulator.nan_pose = False, True
            spin_nodes_until(nodes, lambda: bridge.skipped["non-finite"] >= 5)
            emulator.nan_pose = False
            n = len(probe.poses)
            spin_nodes_until(nodes, lambda: len(probe.poses) >= n + 5)
            emulator.restart((4, 2))
            spin_nodes_until(nodes, lambda: bridge.client.stats["version_changes"] == 1)
            n = len(probe.poses)
            spin_nodes_until(nodes, lambda: len(probe.poses) >= n + 5)
        finally:
            bridge.close()
            probe.close()
    assert all(p.tracking_valid for p in probe.poses)
    assert all(np.allclose(p.position_mm, [10.0, 23.5, -2.0], atol=1e-4) for p in probe.poses), \
        "a zero or stale pose was published"
    stamps = [p.stamp_ns for p in probe.poses]
    assert stamps == sorted(stamps)


def test_no_server_exits_2_with_one_line_naming_the_address(graph):
    port = free_udp_port()
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.mocap_bridge", f"command_port:={port}",
                        f"data_port:={free_udp_port()}", "startup_timeout_s:=0.5"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    lines = [l for l in err.decode().splitlines() if "no NatNet server" in l]
    assert len(lines) == 1 and f"127.0.0.1:{port}" in lines[0]


def test_bad_address_parameter_is_exit_2(graph):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.mocap_bridge", "server_address:=motive.local"])
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and "server_address" in err.decode()
