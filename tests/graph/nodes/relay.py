"""Test node: declares a reader and a writer topic and free-form params (for the resolver)."""
import sys

from incipient_slip.messages import BiotacPac, SlipEstimate
from incipient_slip.graph.runtime import Node, run_node


class Relay(Node):
    PARAMS = {"a": None, "b": None, "c": None, "d": None}
    INPUTS = {"/biotac/pac": BiotacPac}
    OUTPUTS = {"/slip/estimate": SlipEstimate}

    def __init__(self, **kwargs):
        super().__init__("relay", **kwargs)
        self.create_subscription(BiotacPac, lambda m: None)
        self.create_publisher(SlipEstimate)


def main(argv=None):
    return run_node(Relay, argv)


if __name__ == "__main__":
    sys.exit(main())
