"""Timers of one node: two due at the same instant with the same period must both run (the heap
compared their callbacks and raised TypeError, killing the node)."""
from incipient_slip.graph.runtime import Timer


def test_timers_due_together_order_without_comparing_callbacks():
    import heapq
    heap = []
    a, b = Timer(1.0, 1.0, lambda: None), Timer(1.0, 1.0, print)
    heapq.heappush(heap, a)
    heapq.heappush(heap, b)          # TypeError before: '<' between two callables
    assert {id(heapq.heappop(heap)), id(heapq.heappop(heap))} == {id(a), id(b)}


def test_a_due_timer_runs_after_the_messages_already_received(graph):
    """A watchdog timer judges silence on what has arrived: after a stall (a loaded host did not
    run the node) the messages waiting in its socket are handled before the due timer runs.
    Before, one message per spin was handled and then the timer: a pzt_injector starved for
    1 s saw "no heartbeat for 1 s" with the heartbeats in its queue and switched the PZT off."""
    import zmq

    from incipient_slip import messages as M
    from incipient_slip.graph.runtime import Node
    from incipient_slip.messages import Heartbeat

    node = Node("watchdog", graph_dir=graph.dir, heartbeat_s=0)
    try:
        heard, seen_by_timer = [], []
        node.create_subscription(Heartbeat, heard.append)
        node.create_timer(0.001, lambda: seen_by_timer.append(len(heard)))
        frames = []
        for i in range(5):
            frames += [Frame(Heartbeat.TOPIC.encode() + b"\0", True),
                       Frame(M.encode(Heartbeat(node="other", pid=1), seq=i), False)]

        class Socket:                      # the node's socket after the stall: 5 heartbeats waiting
            def recv(self, flags=0, copy=True):
                if frames:
                    return frames.pop(0)
                raise zmq.Again()

            def setsockopt(self, *args):
                pass
        real, node._sub = node._sub, Socket()
        node._timers[0].due = 0.0          # the timer came due during the stall
        node.spin_once(0.0)
        node._sub = real
        assert seen_by_timer[:1] == [5]
    finally:
        node.close()


class Frame:
    """What zmq's recv(copy=False) returns, as the runtime reads it."""

    def __init__(self, data: bytes, more: bool):
        self.bytes, self.more = data, more
