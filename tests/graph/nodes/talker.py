"""Test node: publishes a P_AC frame every 1/rate_hz s; exits with exit_code after count frames.

Before the first frame it waits for the named readers of its launch (`wait_readers`), or for
`wait_for` subscribers by count (started by hand)."""
import sys

import numpy as np

from incipient_slip.messages import BiotacPac
from incipient_slip.graph.runtime import Node, run_node


class Talker(Node):
    PARAMS = {"rate_hz": 100.0, "count": 0, "exit_code": 0, "wait_for": 0, "wait_readers": False}
    INPUTS: dict = {}
    OUTPUTS = {"/biotac/pac": BiotacPac}

    def __init__(self, **kwargs):
        super().__init__("talker", **kwargs)
        self.pub = self.create_publisher(BiotacPac)
        if self.param("wait_readers"):
            self.wait_for_readers(timeout_s=20.0)
        if self.param("wait_for"):
            self.pub.wait_for_subscribers(self.param("wait_for"), 10.0)
        self.sent = 0
        self.create_timer(1.0 / self.param("rate_hz"), self.tick)

    def tick(self):
        self.pub.publish(BiotacPac(pac_counts=np.full(22, self.sent % 1000, dtype=np.int16)))
        self.sent += 1
        if self.param("count") and self.sent >= self.param("count"):
            self.shutdown(f"sent {self.sent}", self.param("exit_code"))


def main(argv=None):
    return run_node(Talker, argv)


if __name__ == "__main__":
    sys.exit(main())
