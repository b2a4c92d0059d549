"""Rig identification, the period windows: which samples make period k's `Observation`.

Pure bookkeeping, no sockets (the `identifier` node feeds it what it hears). Two clocks:

* lock-step (rig_sim, `clock: tick_end`): period k is [k T, (k+1) T) of the rig's stamps and ends
  at the rig's tick k;
* real time (device nodes, `clock: tick_start`): the stage's tick k says period k's move is done,
  and the period is the window [tick + settle, tick + settle + T) of host-time stamps (the pad, the
  robot's press and an emulated rig's own 500 ms step settle first).

A period is complete once 90 % of its mocap samples are in, or a later sample shows none will
come. On a real-time rig a window with under half of them (a hole in the stream: a loaded host, a
lost marker) is observed again over the next T, counted; after `max_retries` such windows the
identification gives up (`WindowRetry.give_up`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from incipient_slip.messages import PERIOD_NS

from .protocol import Observation


@dataclass(frozen=True)
class WindowRetry:
    """Period `period`'s window held only `samples` mocap samples: observed again (or, when
    `give_up`, not: more than the allowed windows were retried)."""

    period: int
    samples: int
    retried: int
    give_up: bool


class PeriodWindows:
    """Ticks, mocap samples and F_N samples in; each period's Observation out, in order."""

    def __init__(self, real_time: bool, mocap_rate_hz: float, settle_s: float = 0.0, origin_mm: float = 0.0,
                 max_retries: int = 20, period_ns: int = PERIOD_NS):
        self.real_time, self.settle_ns, self.origin_mm = real_time, int(settle_s * 1e9), origin_mm
        self.max_retries, self.period_ns = max_retries, period_ns
        self.need = 0.9 * mocap_rate_hz * period_ns / 1e9
        self.poses: list[tuple[int, float]] = []
        self.forces: list[tuple[int, float]] = []
        self.ticks: dict[int, float] = {}
        self.window_start: dict[int, int] = {}       # real time: period -> first stamp of its window
        self.next_period = 0
        self.retried = 0

    def pose(self, stamp_ns: int, travel_mm: float) -> None:
        self.poses.append((stamp_ns, travel_mm))

    def force(self, stamp_ns: int, normal_force_kpa: float) -> None:
        self.forces.append((stamp_ns, normal_force_kpa))

    def tick(self, period: int, stamp_ns: int, position_mm: float) -> None:
        """The actuator's tick of `period` at its absolute position (the origin is taken off)."""
        self.ticks[period] = position_mm - self.origin_mm
        if self.real_time:
            self.window_start[period] = stamp_ns + self.settle_ns

    def next(self) -> Observation | WindowRetry | None:
        """Return the next period's Observation when its window is complete, a WindowRetry when
        its window had a hole (call again: the same period is then observed over the next T),
        or None while it waits for a tick or samples."""
        k = self.next_period
        if k not in self.ticks:
            return None
        lo = self.window_start[k] if self.real_time else k * self.period_ns
        hi = lo + self.period_ns
        inside = [(s, y) for s, y in self.poses if lo <= s < hi]
        if len(inside) < self.need and not any(s >= hi for s, _ in self.poses):
            return None
        if len(inside) < 0.5 * self.need and self.real_time:
            return self._retry(k, hi, len(inside))
        return self._observe(k, lo, hi, inside)

    def _retry(self, k: int, hi: int, samples: int) -> WindowRetry:
        self.retried += 1
        if self.retried > self.max_retries:
            return WindowRetry(k, samples, self.retried - 1, True)
        self.window_start[k] = hi
        self.poses = [(s, y) for s, y in self.poses if s >= hi]
        return WindowRetry(k, samples, self.retried, False)

    def _observe(self, k: int, lo: int, hi: int, inside: list) -> Observation:
        """Period k's Observation: its mocap samples, the last F_N before its end, its tick's position."""
        self.poses = [(s, y) for s, y in self.poses if s >= hi]
        force = [f for s, f in self.forces if s < hi]
        self.forces = [(s, f) for s, f in self.forces if s >= lo]
        t = np.array([s for s, _ in inside], float) / 1e9
        y = np.array([v for _, v in inside], float)
        self.next_period += 1
        return Observation(k, force[-1] if force else math.nan, self.ticks.pop(k), hi / 1e9, t, y)
