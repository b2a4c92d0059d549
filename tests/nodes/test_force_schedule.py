"""force_schedule answers each tick with the collection protocol's next F_N draw, once per period."""
from __future__ import annotations

import pytest

from incipient_slip.messages import ActuatorState, GripCommand
from incipient_slip.sim.protocols import collection_forces_kpa

STEPS = 6


@pytest.mark.timeout(60)
def test_each_tick_asks_for_the_next_periods_draw_once(graph, probe):
    proc = graph.spawn(["python", "-m", "incipient_slip.nodes.force_schedule", "seed:=11", f"steps:={STEPS}"])
    commands = probe.listen(GripCommand)
    tick = probe.node.create_publisher(ActuatorState)
    probe.until(lambda: tick.wait_for_subscribers(1, 0.05), 30, procs=[proc], what="force_schedule subscribed")
    for k in [0, 1, 1, 2, 3, 4, 5]:                  # a repeated tick is not answered twice
        tick.publish(ActuatorState(position_mm=0.1 * k, period=k, stamp_ns=(k + 1) * 500_000_000))
    probe.until(lambda: len(commands) >= STEPS, 30, procs=[proc], what=f"{STEPS} commands")
    draws = collection_forces_kpa(11, STEPS)
    assert [c.period for c in commands] == list(range(STEPS))
    assert [c.normal_force_kpa for c in commands] == [float(draws[min(k + 1, STEPS - 1)]) for k in range(STEPS)]
    assert not any(c.hold for c in commands)
