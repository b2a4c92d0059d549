"""rig_sim -> estimator -> (a test controller) -> rig_sim in lock-step, as real processes: each
period gets one estimate, the rig waits for the answer to it, and every valid estimate equals
the model applied offline to the same window of the in-process simulation (the stamps of the
node path and the sample indices of the data set path cut the same windows)."""
from __future__ import annotations

import signal

import numpy as np
import pytest

from incipient_slip.messages import ActuatorState, GripCommand, Heartbeat, ObjectPose, RobotState, SlipEstimate
from incipient_slip.models.features import feature_spec, phi
from incipient_slip.models.modelfile import Model, save_model
from incipient_slip.graph.runtime import Node
from incipient_slip.sim.rig import Rig, load_scene
from waiting import spin_until


class AnsweringController(Node):
    """Answers each SlipEstimate(period=k) with GripCommand(period=k) at a scheduled force."""

    def __init__(self, graph_dir, forces):
        super().__init__("test_controller", graph_dir=graph_dir, heartbeat_s=0)
        self.forces = forces
        self.estimates: list[SlipEstimate] = []
        self.ticks: list[ActuatorState] = []
        self.estimators = set()
        self.grip = self.create_publisher(GripCommand)
        self.create_subscription(SlipEstimate, self.on_estimate)
        self.create_subscription(Heartbeat, lambda h: self.estimators.add(h.node))
        for t in (ObjectPose, RobotState):       # rig_sim waits for a subscriber on each topic
            self.create_subscription(t, lambda m: None)

    def listen_to_ticks(self):
        # only now may the rig start: we hear the estimator, so no estimate can be missed
        self.create_subscription(ActuatorState, self.ticks.append)

    def on_estimate(self, msg):
        self.estimates.append(msg)
        self.grip.publish(GripCommand(normal_force_kpa=self.forces[msg.period + 1], period=msg.period))

    def spin_until(self, predicate, procs, timeout_s=30.0):
        spin_until(lambda: self.spin_once(0.02), predicate, timeout_s, procs)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("method, scene", [("injection", "paper"), ("e19", "electrodes_only")])
def test_estimates_on_the_rig_equal_the_offline_model_on_the_same_windows(graph, tmp_path, method, scene):
    steps, seed, material = 12, 4, "petg"
    forces = [round(2.0 + 0.3 * (k % 7), 1) for k in range(steps + 1)]
    spec = feature_spec(method)
    n = spec.n_features
    model = Model(spec=spec, kind="linear", mean=np.full(n, 1.0 if method == "injection" else 2000.0),
                  scale=np.full(n, 3.0 if method == "injection" else 500.0),
                  weights=np.random.default_rng(3).normal(0, 0.1, n), intercept=0.5)
    save_model(model, tmp_path / "m.npz")

    estimator = graph.spawn(["python", "-m", "incipient_slip.nodes.estimator", f"method:={method}",
                             f"model:={tmp_path / 'm.npz'}"])
    stream_topic = "/biotac/pac" if method == "injection" else "/biotac/slow"
    rig = graph.spawn(["python", "-m", "incipient_slip.nodes.rig_sim", f"scene:={scene}",
                       f"material:={material}", f"seed:={seed}", f"steps:={steps}",
                       f"normal_force_kpa:={forces[0]}", "wait_timeout_s:=20",
                       "max_step_kpa:=6.0",        # the schedule jumps; the rig is only the plant here
                       # nobody reads the other BioTac topic: wait only for what is read
                       f'wait_topics:=["{stream_topic}", "/object/pose", "/robot/state", "/actuator/state"]'])
    ctl = AnsweringController(graph.dir, forces)
    ctl.spin_until(lambda: "estimator" in ctl.estimators, [estimator, rig])
    ctl.listen_to_ticks()
    ctl.spin_until(lambda: len(ctl.ticks) == steps and len(ctl.estimates) == steps, [estimator, rig])

    sim = Rig(load_scene(scene), material, seed)
    outs = [sim.step_period(forces[k]) for k in range(steps)]
    assert [e.period for e in ctl.estimates] == list(range(steps))
    assert not ctl.estimates[0].valid                       # half a window
    if method == "injection":
        stream, per_period = np.concatenate([o.pac_counts for o in outs]), 1100
    else:
        stream, per_period = np.concatenate([o.electrode_counts for o in outs]), 50
    width = spec.window_samples
    for e in ctl.estimates[1:]:
        stop = per_period * (e.period + 1)
        want = float(model.predict(phi(stream[stop - width:stop][None], spec))[0])
        assert e.valid and e.stick_ratio == pytest.approx(want, abs=1e-9), e
    ctl.close()
    for p in (rig, estimator):
        p.terminate()
        assert p.wait(10) == 128 + signal.SIGTERM
