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
