"""The `slip` command: one entry point whose sub-commands live beside the code they drive.

Each area module exposes `register(subparsers)`; this file only lists the modules, so adding a
command never means editing another area's code. A handler returns an exit code or raises
`UsageError`, which `main` prints as one line on stderr (exit 2, no traceback).
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys

from incipient_slip.errors import EXIT_INTERRUPTED, EXIT_USAGE, UsageError

# each module defines register(subparsers) -> None
COMMAND_MODULES = (
    "incipient_slip.graph.tools",        # topic list|echo|hz, bag record|play|info
    "incipient_slip.sim.cli",            # dataset
    "incipient_slip.models.cli",         # train, evaluate
    "incipient_slip.experiments.cli",    # reproduce NAME|--list
    "incipient_slip.experiments.run_plot",  # run plot SUMMARY
    "incipient_slip.nodes.device_tools", # robot recover, rig check
    "incipient_slip.nodes.foxglove_bridge",  # view
)


def build_parser(modules: tuple[str, ...] = COMMAND_MODULES) -> argparse.ArgumentParser:
    """Return the `slip` parser with the commands of `modules`."""
    parser = argparse.ArgumentParser(
        prog="slip",
        description="Incipient slip detection by vibration injection: tools for the node graph, "
        "the simulated rig, the slip models and the paper's experiments.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module_name in modules:
        importlib.import_module(module_name).register(subparsers)
    return parser


def _where(args: argparse.Namespace) -> str:
    """Return the command line's command words, e.g. 'slip reproduce stabilization'."""
    words = [args.command] + [getattr(args, a) for a in ("tool", "experiment")
                              if isinstance(getattr(args, a, None), str)]
    return " ".join(["slip", *words])


def main(argv: list[str] | None = None, modules: tuple[str, ...] = COMMAND_MODULES) -> int:
    """Runs `slip` (or, with `modules`, a subset of its commands); returns the exit code."""
    # `slip ... | head` should end quietly when the reader goes away, like any Unix tool.
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    args = build_parser(modules).parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"{_where(args)}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
