"""What a queue holds now, taken without waiting: the loop that a link's reader (the Cheetah's
batches, the robot link's jobs and events) runs on each poll."""
from __future__ import annotations

import queue
from typing import Iterator

__all__ = ["waiting"]


def waiting(q) -> Iterator:
    """Yields the items `q` (a `queue.Queue` or a multiprocessing queue) holds, oldest first, until
    `get_nowait` finds it empty; an item put meanwhile is yielded too. A caller that stops early
    leaves the rest on the queue."""
    while True:
        try:
            item = q.get_nowait()
        except queue.Empty:
            return
        yield item
