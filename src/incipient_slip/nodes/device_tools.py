"""`slip robot recover` and `slip rig check`: the operator's tools for the device nodes."""
from __future__ import annotations

import time

from incipient_slip.errors import UsageError
from incipient_slip.graph import discovery
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import RobotRecover, RobotState

__all__ = ["register", "cmd_robot_recover"]


class RecoverRequest(Node):
    """Publishes one RobotRecover and collects the robot states that follow."""

    def __init__(self, **kwargs):
        super().__init__("slip_robot_recover", heartbeat_s=0, **kwargs)
        self.pub = self.create_publisher(RobotRecover)
        self.states: list[RobotState] = []
        self.create_subscription(RobotState, self.states.append)


def cmd_robot_recover(args) -> int:
    """Asks the running ur5 node to recover; 0 once it reports `ready`, 1 if it does not."""
    kwargs = {"graph_dir": discovery.graph_dir(args.graph)} if args.graph else {}
    with RecoverRequest(**kwargs) as node:
        if not node.pub.wait_for_subscribers(1, args.timeout):
            raise UsageError(f"no ur5 node reads {RobotRecover.TOPIC} in this graph "
                             f"(is `launch ... rig:=hardware` running? --graph?)")
        sent_ns = time.time_ns()
        node.pub.publish(RobotRecover(note=args.note))
        print("recovery requested; waiting for the robot node", flush=True)
        deadline = time.monotonic() + args.timeout
        while time.monotonic() < deadline:
            node.spin_once(0.05)
            fresh = [s for s in node.states if s.stamp_ns > sent_ns]
            if fresh and fresh[-1].state == "ready":
                print("robot ready", flush=True)
                return 0
        last = node.states[-1].state if node.states else "no state received"
        print(f"robot not ready after {args.timeout:g} s ({last}); the ur5 node's log says why "
              f"(an engaged emergency stop must be released on the pendant first)", flush=True)
        return 1


def cmd_rig_check(args) -> int:
    """Runs rig_check once on `--config`; 2 with one line per missing device."""
    argv = [f"rig_config:={args.config}", f"timeout_s:={args.timeout}", "stay:=false"]
    if args.biotac_port:
        argv.append(f"biotac_port:={args.biotac_port}")
    if args.pzt_device is not None:
        argv += ["pzt:=true", f"pzt_device:={args.pzt_device}"]
    return run_node(_rig_check_class(), argv)


def _rig_check_class():
    from incipient_slip.nodes.rig_check import RigCheck
    return RigCheck


def register(subparsers) -> None:
    """Adds `slip robot recover` and `slip rig check` to the `slip` command."""
    robot = subparsers.add_parser("robot", help="the UR5 robot node of a running hardware graph")
    rsub = robot.add_subparsers(dest="tool", metavar="TOOL", required=True)
    p = rsub.add_parser("recover", help="after a protective or emergency stop, once you have "
                        "inspected and removed its cause: unlock, power on, restart the control "
                        "script (the robot node never does this by itself)")
    p.add_argument("--graph", metavar="NAME", help="graph name (default $SLIP_GRAPH or 'default')")
    p.add_argument("--timeout", type=float, default=15.0, metavar="S",
                   help="wait this long for the robot to be ready (default 15 s)")
    p.add_argument("--note", default="", help="a note for the robot node's log")
    p.set_defaults(func=cmd_robot_recover)
    rig = subparsers.add_parser("rig", help="the real rig's devices")
    gsub = rig.add_subparsers(dest="tool", metavar="TOOL", required=True)
    p = gsub.add_parser("check", help="which devices of the rig configuration answer "
                        "(one line per missing device, exit 2)",
                        description="Probes every device section of --config at once (NatNet, Zaber, "
                        "UR5), and the BioTac bridge and the PZT's sound card when asked, as the gate of "
                        "`launch ... rig:=hardware` does: one line per missing device (what to check), "
                        "exit 2; exit 0 when all answer. What each line means: docs/hardware/setup.md "
                        "(section 'What rig check's lines mean').")
    p.add_argument("--config", required=True, metavar="FILE",
                   help="your rig configuration: a copy of config/rig.yaml with your lab's addresses "
                   "(the shipped file's addresses are examples, so there is no default)")
    p.add_argument("--timeout", type=float, default=3.0, metavar="S",
                   help="each device must answer within this (default 3 s)")
    p.add_argument("--biotac-port", default="", metavar="PORT",
                   help="also check the BioTac bridge's serial port (e.g. /dev/ttyACM0)")
    p.add_argument("--pzt-device", nargs="?", const="", default=None, metavar="CARD",
                   help="also check the PZT amplifier's sound card (sounddevice name or index; "
                   "without CARD: the default output), as `launch ... rig:=hardware` does")
    p.set_defaults(func=cmd_rig_check)
