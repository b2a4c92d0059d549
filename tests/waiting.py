"""The one way tests wait on a graph: spin until a condition holds (`spin_until`), or until a
publisher's readers subscribed (`handshake`), fail on timeout, and count a
watched process's exit as a failure only after reading what it sent before it ended.

A node that ends by design (`exit_when_done`, a launch's last step) may have sent its last
messages just before: they are still queued for the reader when its exit is seen. So an exit
fails the wait only if the condition still fails after up to READ_AFTER_EXIT_S of reading.
(Imported by name, as `waiting`: tests/ is on sys.path through its conftest.py; a helper in
conftest.py itself cannot be imported, tests/models/conftest.py shares the module name.)
"""
from __future__ import annotations

import time
from typing import Callable, Iterable

import pytest

READ_AFTER_EXIT_S = 2.0


def spin_until(spin: Callable[[], object], predicate: Callable[[], bool], timeout_s: float,
               procs: Iterable = (), what: str = "") -> None:
    """Calls `spin()` (which reads what arrived, briefly blocking) until `predicate()`."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        for proc in procs:
            if proc.poll() is not None and not _read_what_is_left(spin, predicate):
                err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                pytest.fail(f"waiting for {what or predicate}: {proc.args[:4]} exited "
                            f"with {proc.returncode}:\n{err[-3000:]}")
        if time.monotonic() > deadline:
            pytest.fail(f"waiting for {what or predicate}: not within {timeout_s} s")
        spin()


def handshake(pub, timeout_s: float = 20.0, procs: Iterable = (), what: str = "", n: int = 1) -> None:
    """Waits until `n` subscriptions match publisher `pub`'s topic (the slow-joiner handshake: what
    `pub` sends next reaches them), failing on timeout or when one of `procs` exited first."""
    spin_until(lambda: None, lambda: pub.wait_for_subscribers(n, 0.1), timeout_s, procs,
               what or f"{n} subscriber(s) of {pub.topic}")


def _read_what_is_left(spin: Callable[[], object], predicate: Callable[[], bool]) -> bool:
    until = time.monotonic() + READ_AFTER_EXIT_S
    while not predicate() and time.monotonic() < until:
        spin()
    return predicate()
