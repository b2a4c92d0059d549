"""The run's period clock: message stamps mapped onto periods, where period k is [k T, (k+1) T).

Used by every node that needs a message's period from its stamp (the estimator, the supervisor);
pure: no sockets, no clock of its own.
"""
from __future__ import annotations

from collections import deque

from incipient_slip.messages import PERIOD_NS

PERIOD_ORIGINS = ("stamps", "tick")


class PeriodOrigin:
    """Maps message stamps onto the run's period clock, where period k is [k T, (k+1) T).

    `stamps`: the stamps already are that clock (the simulated rig's start at 0). `tick`: device
    clocks (host time, rig:=emulated and hardware): period k ends at the actuator's tick k, so the
    first tick sets the origin (its stamp less (k + 1) T). Until then messages are held (at most
    `held_max`, oldest dropped first) and `tick()` hands them back to be replayed; a stamp at or
    before the origin is before period 0 (`relative` returns None).
    """

    def __init__(self, mode: str = "stamps", held_max: int = 1000, period_ns: int = PERIOD_NS):
        if mode not in PERIOD_ORIGINS:
            raise ValueError(f"period origin {mode!r}; expected one of {', '.join(PERIOD_ORIGINS)}")
        self.mode, self.period_ns = mode, period_ns
        self.origin_ns: int | None = 0 if mode == "stamps" else None
        self.held: deque = deque(maxlen=max(1, held_max))
        self.before_origin = 0             # messages stamped before period 0 (counted, dropped)

    def hold(self, item) -> bool:
        """True (and keeps `item`) while the origin is not known yet."""
        if self.origin_ns is not None:
            return False
        self.held.append(item)
        return True

    def tick(self, period: int, stamp_ns: int) -> list:
        """Sets the origin from the first tick (the end of `period`); returns the held messages,
        in arrival order."""
        if self.origin_ns is not None:
            return []
        self.origin_ns = stamp_ns - (period + 1) * self.period_ns
        held, self.held = list(self.held), deque()
        return held

    def relative(self, stamp_ns: int) -> int | None:
        """Return the stamp on the period clock; None before period 0 (counted) or before the origin is known."""
        if self.origin_ns is None:
            return None
        if self.mode == "stamps":
            return stamp_ns
        rel = stamp_ns - self.origin_ns
        if rel <= 0:
            self.before_origin += 1
            return None
        return rel
