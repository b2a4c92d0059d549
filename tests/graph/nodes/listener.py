"""Test node: counts P_AC frames; prints the first seq, a line per `report_every` frames; exits after `count`.
`refuse`: its constructor refuses its input once started (exit 2), as a viewer bridge whose port
was taken after the launch's check does."""
import sys
import time

from incipient_slip.messages import BiotacPac
from incipient_slip.graph.params import ParamError
from incipient_slip.graph.runtime import Node, run_node


class Listener(Node):
    PARAMS = {"count": 0, "report_every": 0, "start_delay_s": 0.0, "refuse": False}
    INPUTS = {"/biotac/pac": BiotacPac}
    OUTPUTS: dict = {}

    def __init__(self, **kwargs):
        super().__init__("listener", **kwargs)
        time.sleep(self.param("start_delay_s"))     # a slow start (a model being loaded)
        if self.param("refuse"):
            raise ParamError("node 'listener': refused its input (as a port taken since the check)")
        self.sub = self.create_subscription(BiotacPac, self.on_pac)

    def on_pac(self, msg):
        n = self.sub.received
        if n == 1:
            print(f"first seq {msg.seq}", flush=True)
        if self.param("report_every") and n % self.param("report_every") == 0:
            print(f"received {n} seq {msg.seq} gaps {self.sub.gaps} dropped {self.sub.dropped}")
        if self.param("count") and n >= self.param("count"):
            print(f"done {n} gaps {self.sub.gaps}", flush=True)
            self.shutdown("got all")


def main(argv=None):
    return run_node(Listener, argv)


if __name__ == "__main__":
    sys.exit(main())
