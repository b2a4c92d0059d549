"""devices.queues.waiting: what a queue holds now, without waiting."""
import multiprocessing
import queue
import time

from incipient_slip.devices.queues import waiting


def test_yields_what_the_queue_holds_in_order_and_stops_when_it_is_empty():
    q = queue.Queue()
    for item in (1, 2, 3):
        q.put(item)
    assert list(waiting(q)) == [1, 2, 3]
    assert list(waiting(q)) == []


def test_a_caller_that_stops_early_leaves_the_rest_on_the_queue():
    q = queue.Queue()
    for item in ("a", "quit", "b"):
        q.put(item)
    for item in waiting(q):
        if item == "quit":
            break
    assert q.get_nowait() == "b" and q.empty()


def test_an_item_put_while_draining_is_yielded_too():
    q = queue.Queue()
    q.put(0)
    seen = []
    for item in waiting(q):
        seen.append(item)
        if item < 2:
            q.put(item + 1)
    assert seen == [0, 1, 2]


def test_a_multiprocessing_queue_drains_as_well():
    q = multiprocessing.get_context("spawn").Queue()
    q.put("x")
    q.put("y")
    seen, deadline = [], time.monotonic() + 10
    while len(seen) < 2 and time.monotonic() < deadline:     # the feeder thread may lag the put
        seen += waiting(q)
    assert seen == ["x", "y"]
    q.close()
    q.join_thread()
