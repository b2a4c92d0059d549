"""Test node: exits with `code` after `after_s` seconds (0: runs until signalled); its shutdown
takes `flush_s` seconds (a flush that a loaded machine makes slow)."""
import sys
import time

from incipient_slip.graph.params import Param
from incipient_slip.graph.runtime import Node, run_node


class Exiter(Node):
    PARAMS = {"after_s": Param(0.0, lo=0.0, help="seconds before it exits; 0: never"),
              "code": Param(0, lo=0, hi=255, help="its exit code"),
              "flush_s": Param(0.0, lo=0.0, help="seconds its on_shutdown takes")}
    INPUTS: dict = {}
    OUTPUTS: dict = {}

    def __init__(self, **kwargs):
        super().__init__("exiter", **kwargs)
        if self.param("flush_s") > 0:
            self.on_shutdown(lambda: time.sleep(self.param("flush_s")))
        if self.param("after_s") > 0:
            self.create_timer(self.param("after_s"), lambda: self.shutdown("time is up", self.param("code")))


def main(argv=None):
    return run_node(Exiter, argv)


if __name__ == "__main__":
    sys.exit(main())
