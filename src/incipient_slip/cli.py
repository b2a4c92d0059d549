"""The `slip` command: one entry point whose sub-commands live beside the code they drive.

Each area module exposes `register(subparsers, reproduce)`: `subparsers` takes top-level
commands, `reproduce` takes the experiments of `slip reproduce NAME`. This file only lists the
modules, so adding a command never means editing another area's code.
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys

# each module defines register(subparsers, reproduce) -> None
COMMAND_MODULES = (
    "incipient_slip.graph.tools",       # topic list|echo|hz, bag record|play|info
    "incipient_slip.sim.cli",           # dataset, sim calibrate
    "incipient_slip.models.cli",        # train, evaluate, reproduce estimation, model regen
    "incipient_slip.control_cli",       # reproduce stabilization
)


def fail(msg: str, where: str = "slip") -> int:
    """Reports bad user input as one line on stderr (no traceback); returns exit code 2."""
    print(f"{where}: error: {msg}", file=sys.stderr)
    return 2


def build_parser(modules: tuple[str, ...] = COMMAND_MODULES) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="slip",
        description="Incipient slip detection by vibration injection: tools for the node graph, "
        "the simulated rig, the slip models and the paper's experiments.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    reproduce = subparsers.add_parser(
        "reproduce", help="run one of the paper's experiments end to end and write docs/"
    ).add_subparsers(dest="experiment", metavar="EXPERIMENT", required=True)
    for module_name in modules:
        importlib.import_module(module_name).register(subparsers, reproduce)
    return parser


def main(argv: list[str] | None = None, modules: tuple[str, ...] = COMMAND_MODULES) -> int:
    """Runs `slip` (or, with `modules`, a subset of its commands); returns the exit code."""
    # `slip ... | head` should end quietly when the reader goes away, like any Unix tool.
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    args = build_parser(modules).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
