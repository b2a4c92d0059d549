"""estimator: the stick-ratio estimate of each 500 ms period, from the P_AC or electrode stream.

    python -m incipient_slip.nodes.estimator method:=injection

Loads `model` (default the shipped model of `method` trained on `label`: `models/<method>.npz`
for the paper's pseudo label, `models/measured-ratio/<method>.npz`, the default; its feature spec
must fit the stream, its header's label must be `label` when one is given, and its window is `window_s`) and reads `/biotac/pac` (vibration methods) or `/biotac/slow` (electrode
methods). The scheduling by stamps, validity after seq gaps and stale streams, and the
wall-clock watchdog are `models.estimator_core.PeriodEstimator`; this node wires it.

`period_origin: tick` (device clocks, rig:=emulated and hardware; rig:=replay, whose recording may
be of either): the sensor's stamps are host
time, so period k is not stamp // T. Period k then ends at the stamp of the actuator's tick for
step k (`control.PeriodOrigin`): the core sees stamps relative to the first tick's origin;
frames before that tick wait (at most `origin_buffer_s`) and are then replayed, those before the
origin dropped and counted. Estimates are stamped on the host clock.
`period_origin: stamps` (default; the simulated rig's stamps start at 0) uses the stamps as they are.
"""
from __future__ import annotations

import time

from incipient_slip.control import PERIOD_ORIGINS, PeriodOrigin
from incipient_slip.graph.params import Param, ParamError
from incipient_slip.graph.runtime import Node, run_node
from incipient_slip.messages import PAC_SAMPLES_PER_FRAME, PERIOD_NS, ActuatorState, BiotacPac, BiotacSlow, PztState, SlipEstimate
from incipient_slip.models.estimator_core import (
    ModelFileError, PeriodEstimator, default_model_path, load_model,
)
from incipient_slip.models.features import METHODS
from incipient_slip.models.labels import DEFAULT_LABEL, LABELS, SHIPPED_LABELS, rule_of_header


class Estimator(Node):
    """Buffers the sensor stream and publishes one SlipEstimate per period (by stamps)."""

    INPUTS = {BiotacPac.TOPIC: BiotacPac, BiotacSlow.TOPIC: BiotacSlow, PztState.TOPIC: PztState,
              ActuatorState.TOPIC: ActuatorState}
    OUTPUTS = {SlipEstimate.TOPIC: SlipEstimate}
    PARAMS = {
        "method": Param("injection", choices=METHODS, help="estimation method"),
        "label": Param("", choices=("",) + LABELS, help="the training label of the model (docs/estimation.md): "
                       f"pseudo, the paper's (models/<method>.npz); measured-ratio (models/measured-ratio/); \"\": "
                       f"{DEFAULT_LABEL}, or what model:= was trained on; with model:=, a label that differs "
                       "from the file's is refused"),
        "model": Param("", help='model file ("": the shipped model of method and label)'),
        "window_s": Param(0.0, lo=0.0, help="0: the model's window; otherwise must equal it (s)"),
        "stale_after_s": Param(0.05, lo=0.0, help="newest sample older than this before a boundary: stale (s)"),
        "wall_timeout_s": Param(2.0, lo=0.0, help="no frame for this long (wall clock): stale; 0 = off (s)"),
        "period_origin": Param("stamps", choices=PERIOD_ORIGINS,
                               help="stamps: period k ends at stamp (k+1) T; tick: at the actuator's tick k (device clocks)"),
        "origin_buffer_s": Param(2.0, lo=0.0, hi=60.0, help="frames kept until the first tick (period_origin tick), s"),
    }

    @classmethod
    def check_inputs(cls, params: dict, name: str = "estimator"):
        """The model file `model` (or the shipped one of method and label) loaded and checked
        against method, window and label; ParamError naming the file (a launch: before any node
        starts, so a missing model is not found after the rig has begun). Returns (model, path,
        the `LabelRule` the model was trained on). The launcher runs it in its own process before
        it starts the node processes; the node runs it once more in its own, in `__init__`."""
        label = params["label"]
        if not params["model"] and label and label not in SHIPPED_LABELS:
            raise ParamError(f"node {name!r}: no shipped models are trained on label {label!r} (shipped: "
                             f"{', '.join(SHIPPED_LABELS)}); train one (slip train --label {label}) and pass model:=FILE")
        path = params["model"] or default_model_path(params["method"], label or DEFAULT_LABEL)
        try:
            model = load_model(path, method=params["method"], window_s=params["window_s"] or None)
        except ModelFileError as exc:     # run_node reports a ParamError in one line, exit 2
            raise ParamError(f"node {name!r}: {exc}") from None
        trained_on = rule_of_header(model.header)
        if label and trained_on.name != label:
            raise ParamError(f"node {name!r}: model {path} was trained on label {trained_on.name!r}, "
                             f"not {label!r} (label:={trained_on.name}, or another model:=)")
        return model, path, trained_on

    def __init__(self, **kwargs):
        super().__init__("estimator", **kwargs)
        model, path, trained_on = self.check_inputs(self.params, self.name)
        self.core = PeriodEstimator(model, PERIOD_NS, round(self.param("stale_after_s") * 1e9),
                                    self.param("wall_timeout_s"))
        pac = model.spec.stream == "pac"
        self.counts_of = (lambda m: m.pac_counts) if pac else (lambda m: m.electrode_counts)
        self.frames = self.create_subscription(BiotacPac if pac else BiotacSlow, self.on_frame,
                                               on_gap=lambda last, seq: self.core.gap())
        self.create_subscription(PztState, self.on_pzt)
        frames_per_s = model.spec.rate_hz / (PAC_SAMPLES_PER_FRAME if pac else 1)
        self.origin = PeriodOrigin(self.param("period_origin"), round(self.param("origin_buffer_s") * frames_per_s))
        if self.origin.origin_ns is None:
            self.create_subscription(ActuatorState, self.on_tick)
        self.estimate_pub = self.create_publisher(SlipEstimate)
        if self.param("wall_timeout_s") > 0:
            self.create_timer(min(0.1, self.param("wall_timeout_s") / 4), self.watchdog)
        self.on_shutdown(self.report)
        self.log(f"method {model.spec.method}, model {path} (label {trained_on}), window {model.spec.window_s} s, stream {self.frames.topic}")

    def on_tick(self, msg: ActuatorState) -> None:
        if self.origin.origin_ns is None:
            held = self.origin.tick(msg.period, msg.stamp_ns)
            self.log(f"period {msg.period} ends at the actuator's tick; {len(held)} frames held")
            for frame in held:
                self.on_frame(frame)

    def on_frame(self, msg) -> None:
        if self.origin.hold(msg):           # period_origin tick: no period before the first tick
            return
        stamp_ns = self.origin.relative(msg.stamp_ns)
        if stamp_ns is None:
            self.warn(f"dropped frame seq {msg.seq}: stamped before period 0 "
                      f"(#{self.origin.before_origin})", throttle_s=1.0, key="origin")
            return
        estimates, warning = self.core.frame(stamp_ns, msg.seq, self.counts_of(msg), time.monotonic())
        if warning:
            self.warn(warning, throttle_s=1.0)
        self.publish(estimates)

    def on_pzt(self, msg: PztState) -> None:
        if self.core.pzt(msg.enabled):
            self.warn(self.core.pzt_problem, throttle_s=1.0)

    def watchdog(self) -> None:
        estimates = self.core.tick(time.monotonic())
        if estimates:
            self.warn(f"no frame for {self.core.wall_timeout_s} s (wall clock): stream stale")
        self.publish(estimates)

    def publish(self, estimates) -> None:
        for e in estimates:
            self.estimate_pub.publish(SlipEstimate(
                stick_ratio=e.stick_ratio, valid=e.valid, method=self.core.method, period=e.period,
                window_end_ns=e.window_end_ns, latency_ns=e.latency_ns, reason=e.reason, cause=e.cause,
                stamp_ns=e.window_end_ns + self.origin.origin_ns))

    def report(self) -> None:
        c, lat = self.core, sorted(self.core.latencies_ns) or [0]
        self.log(f"{c.published} estimates ({c.invalid} invalid), {self.frames.received} frames, "
                 f"{self.frames.gaps} seq gaps, {self.frames.dropped} malformed, {c.refused} refused; "
                 f"latency median {lat[len(lat) // 2] / 1e6:.3f} ms, max {lat[-1] / 1e6:.3f} ms; "
                 f"CPU {time.process_time():.2f} s")


def main(argv=None):
    return run_node(Estimator, argv)


if __name__ == "__main__":
    raise SystemExit(main())
