"""estimator: the stick-ratio estimate of each 500 ms period, from the P_AC or electrode stream.

    python -m incipient_slip.nodes.estimator method:=injection

Loads `model` (default `models/<method>.npz`) with `models.estimator_core.load_model`, which
refuses a file whose feature spec does not fit (method, stream, window); `window_s` is taken
from the file, and a `window_s` param that disagrees with it is an error (exit 2). The model's
stream decides the subscription: `/biotac/pac` for the vibration methods, `/biotac/slow` for
the electrode methods.

Timing follows message stamps only: when a frame holds the last sample before the period
boundary B = (k+1) * period_s, it publishes `SlipEstimate(period=k, window_end_ns=B)` over the
window [B - T, B), with `latency_ns` = the time to compute it. Every boundary gets exactly one
estimate: boundaries that a stream hole or lost frames skipped are estimated (invalid) with
the data that came before them. Validity is the core's: a seq gap or a stamp going backwards
empties the buffer, a stream whose newest sample is more than `stale_after_s` older than B is
"stale", and estimates stay invalid until a full window has refilled. A wall-clock watchdog
(`wall_timeout_s`, 0 = off) handles a stream that stops altogether: it publishes one invalid
"stale" estimate for the next period and empties the buffer. A PZT state that contradicts the
model (injection model, PZT off, or the reverse) makes estimates invalid too.

Malformed frames are dropped and counted by the runtime; frames the core refuses are counted
in `refused`; nothing here blocks.
"""
from __future__ import annotations

import time
from collections import deque

from incipient_slip.messages import (
    PAC_SAMPLES_PER_FRAME, PERIOD_NS, BiotacPac, BiotacSlow, PztState, SlipEstimate,
)
from incipient_slip.models.estimator_core import (
    ModelFileError, StreamError, StreamingEstimator, default_model_path, load_model,
)
from incipient_slip.graph.params import ParamError
from incipient_slip.graph.runtime import Node, run_node

MAX_CATCH_UP = 20          # boundaries estimated at once after a hole; beyond it, resynchronize
SEQ_GAP, STALE = "seq gap", "stale"


class Estimator(Node):
    """Buffers the sensor stream and publishes one SlipEstimate per period (by stamps)."""

    PARAMS = {
        "method": "injection",
        "model": "",                      # "": models/<method>.npz
        "window_s": 0.0,                  # 0: the model's window; otherwise must equal it
        "period_s": PERIOD_NS / 1e9,
        "stale_after_s": 0.05,            # newest sample older than this before B: stale
        "wall_timeout_s": 2.0,            # no frame for this long (wall clock): stale; 0 = off
    }

    def __init__(self, **kwargs):
        super().__init__("estimator", **kwargs)
        self.method = self.param("method")
        if self.method == "none":
            raise ParamError(f"node {self.name!r}: method 'none' (no action) has no estimate; "
                             "leave the estimator out of the launch")
        path = self.param("model") or default_model_path(self.method)
        try:
            self.model = load_model(path, method=self.method, window_s=self.param("window_s") or None)
        except ModelFileError as exc:     # run_node reports a ParamError in one line, exit 2
            raise ParamError(f"node {self.name!r}: {exc}") from None
        spec = self.model.spec
        self.core = StreamingEstimator(self.model, stale_after_ns=int(self.param("stale_after_s") * 1e9))
        self.period_ns = int(round(self.param("period_s") * 1e9))
        self.sample_ns = 1e9 / spec.rate_hz
        msg_type = BiotacPac if spec.stream == "pac" else BiotacSlow
        self.counts_of = ((lambda m: m.pac_counts) if spec.stream == "pac"
                          else (lambda m: m.electrode_counts))
        self.samples_per_frame = PAC_SAMPLES_PER_FRAME if spec.stream == "pac" else 1
        self.frame_sub = self.create_subscription(msg_type, self.on_frame, on_gap=self.on_gap)
        self.create_subscription(PztState, self.on_pzt)
        self.estimate_pub = self.create_publisher(SlipEstimate)
        self.next_end_ns = None           # the next boundary B to estimate
        self.last_stamp_ns = None
        self.last_frame_wall = None
        self.stalled = False
        self.pzt_problem = ""
        self.refused = self.published = self.invalid = 0
        self.latencies_ns: deque = deque(maxlen=10_000)      # for the shutdown summary
        if self.param("wall_timeout_s") > 0:
            self.create_timer(min(0.1, self.param("wall_timeout_s") / 4), self.watchdog)
        self.log(f"method {self.method}, model {path}, window {spec.window_s} s, "
                 f"stream {msg_type.TOPIC}")

    # --- input ---------------------------------------------------------------------------------

    def on_gap(self, last_seq: int, seq: int) -> None:
        # before the callback: boundaries passed during the gap are estimated as invalid
        self.core.reset(SEQ_GAP)

    def on_frame(self, msg) -> None:
        self.last_frame_wall = time.monotonic()
        self.stalled = False
        counts = self.counts_of(msg)
        first_ns = msg.stamp_ns - round((self.samples_per_frame - 1) * self.sample_ns)
        if self.next_end_ns is None or (self.last_stamp_ns is not None and msg.stamp_ns <= self.last_stamp_ns):
            # first frame, or the source restarted its clock: the next boundary after this frame
            self.next_end_ns = (first_ns // self.period_ns + 1) * self.period_ns
        self.last_stamp_ns = msg.stamp_ns
        self.publish_until(first_ns + self.sample_ns / 2)   # boundaries before this frame (a hole)
        try:
            self.core.push(msg.stamp_ns, msg.seq, counts)
        except StreamError as exc:
            self.refused += 1
            self.warn(throttle_s=1.0, key="refused", text=f"refused frame seq {msg.seq}: {exc}")
            return
        # boundaries this frame completes: it holds the last sample before B
        self.publish_until(msg.stamp_ns + 1.5 * self.sample_ns)

    def on_pzt(self, msg: PztState) -> None:
        expected = self.model.spec.injection
        if expected is None or msg.enabled == expected:
            self.pzt_problem = ""
        else:
            self.pzt_problem = (f"PZT is {'on' if msg.enabled else 'off'} but the {self.method} "
                                f"model was trained with injection {'on' if expected else 'off'}")
            self.warn(self.pzt_problem)

    def watchdog(self) -> None:
        timeout = self.param("wall_timeout_s")
        if (self.last_frame_wall is None or self.stalled
                or time.monotonic() - self.last_frame_wall < timeout):
            return
        self.stalled = True
        self.core.reset(STALE)
        self.warn(f"no frame for {timeout} s (wall clock): stream stale")
        self.publish(self.next_end_ns, reason=f"{STALE}: no frame for {timeout} s")
        self.next_end_ns += self.period_ns

    def spin(self) -> int:
        code = super().spin()
        lat = sorted(self.latencies_ns) or [0]
        self.log(f"{self.published} estimates ({self.invalid} invalid), {self.frame_sub.received} "
                 f"frames, {self.frame_sub.gaps} seq gaps, {self.frame_sub.dropped} malformed, "
                 f"{self.refused} refused; latency median {lat[len(lat) // 2] / 1e6:.3f} ms, "
                 f"max {lat[-1] / 1e6:.3f} ms; CPU {time.process_time():.2f} s")
        return code

    # --- output --------------------------------------------------------------------------------

    def publish_until(self, limit_ns: float) -> None:
        """Publishes the estimate of every pending boundary B <= limit_ns, in order."""
        due = int((limit_ns - self.next_end_ns) // self.period_ns) + 1
        if due > MAX_CATCH_UP:
            skipped = due - 1
            self.warn(throttle_s=1.0, key="jump", text=f"stamps jumped {skipped} periods ahead; resynchronizing")
            self.core.reset(STALE)
            self.next_end_ns += skipped * self.period_ns
        while self.next_end_ns <= limit_ns:
            self.publish(self.next_end_ns)
            self.next_end_ns += self.period_ns

    def publish(self, end_ns: int, reason: str = "") -> None:
        t = time.perf_counter_ns()
        if reason:
            ratio, valid = float("nan"), False
        else:
            ratio, valid, reason = self.core.estimate(end_ns)
            if valid and self.pzt_problem:
                ratio, valid, reason = float("nan"), False, self.pzt_problem
        latency = time.perf_counter_ns() - t
        self.latencies_ns.append(latency)
        self.invalid += not valid
        self.estimate_pub.publish(SlipEstimate(
            stick_ratio=ratio, valid=valid, method=self.method, window_end_ns=end_ns,
            latency_ns=latency, period=end_ns // self.period_ns - 1, reason=reason,
            stamp_ns=end_ns))
        self.published += 1


def main(argv=None):
    return run_node(Estimator, argv)


if __name__ == "__main__":
    raise SystemExit(main())
