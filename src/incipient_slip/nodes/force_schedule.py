"""force_schedule: the collection protocol's normal force on a robot, one command per period.

    python -m incipient_slip.nodes.force_schedule seed:=3 steps:=450

The paper collects its data with F_N redrawn every 500 ms period from 1.1, 1.5, ..., 5.9 kPa. On
the simulated rig rig_sim draws them itself; on the emulated and the real rig this node answers
each period's tick (`ActuatorState(period=k)`) with `GripCommand(period=k)` asking for the
next period's draw, the same draws as the simulated rig's (`sim.protocols.collection_forces_kpa`
of the series' seed), and the UR5 node presses to it within its own limits (its position loop,
step and press limits). What F_N the fingertip got is measured (P_DC, `/robot/state`), not
assumed: the data set's F_N comes from the recording (`slip dataset --from-recordings`).
"""
from __future__ import annotations

from incipient_slip.graph.params import Param
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import ActuatorState, GripCommand
from incipient_slip.sim.protocols import collection_forces_kpa


class ForceSchedule(Node):
    """Asks the robot for the collection protocol's F_N of each next period."""

    INPUTS = {ActuatorState.TOPIC: ActuatorState}
    OUTPUTS = {GripCommand.TOPIC: GripCommand}
    PARAMS = {
        "seed": Param(0, lo=0, help="the series' seed: its F_N draws (the simulated rig's for the same seed)"),
        "steps": Param(450, lo=1, help="periods of the series"),
        "wait_subscribers": Param(1, lo=0, help="started by hand: readers of /grip/command to wait for"),
        "wait_timeout_s": Param(10.0, lo=0.0, help="longest wait for them before the first answer (s)"),
    }

    def __init__(self, **kwargs):
        super().__init__("force_schedule", **kwargs)
        self.forces = [float(f) for f in collection_forces_kpa(self.param("seed"), self.param("steps"))]
        self.pub = self.create_publisher(GripCommand)
        self.last = -1
        self.create_subscription(ActuatorState, self.on_tick)
        self.log(f"F_N of {len(self.forces)} periods from seed {self.param('seed')}: {self.forces[:4]} ...")

    def on_tick(self, msg: ActuatorState) -> None:
        k = msg.period
        if k <= self.last:                       # a repeated or old tick: answered already
            self.warn(f"tick {k} after {self.last}: not answered again", throttle_s=1.0)
            return
        if self.last < 0:                        # once: the first answer must not be lost
            self.wait_before_first(self.pub, self.param("wait_subscribers"), self.param("wait_timeout_s"))
        self.last = k
        nxt = self.forces[min(k + 1, len(self.forces) - 1)]
        self.pub.publish(GripCommand(normal_force_kpa=nxt, period=k, reason="collection schedule", cause="schedule"))


def main(argv=None):
    return run_node(ForceSchedule, argv)


if __name__ == "__main__":
    raise SystemExit(main())
