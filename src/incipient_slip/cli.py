"""The `slip` command: one entry point whose sub-commands live beside the code they drive.

Each area module exposes `register(subparsers)`; this file only lists the modules and the command
words each registers, so adding a command never means editing another area's code. `slip WORD ...`
imports only the module of WORD (a command's modules load only when it runs: `slip topic list`
never imports scipy); `slip`, `slip --help` and an unknown word import them all. A handler returns
an exit code or raises `UsageError`, which `main` prints as one line on stderr (exit 2, no
traceback). A full disk, in any command or its workers, is one line too (exit 1): what was being
written, and what under runs/ is safe to delete.
"""
from __future__ import annotations

import argparse
import importlib
import os
import stat
import sys

from incipient_slip import extras
from incipient_slip.errors import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_USAGE, UsageError
from incipient_slip.paths import out_of_space, output_error

EXIT_BROKEN_PIPE = 128 + 13    # what a shell reports for a tool ended by SIGPIPE

# "module" (its register) or "module:function": register(subparsers) -> None, adding exactly
# these commands (a test checks)
COMMANDS = {
    "incipient_slip.graph.tools:register_topic": ("topic", "node", "param"),
    "incipient_slip.graph.tools:register_bag": ("bag",),
    "incipient_slip.graph.keys": ("keys",),
    "incipient_slip.lab.cli": ("dataset", "collect"),
    "incipient_slip.models.cli": ("train", "evaluate"),
    "incipient_slip.experiments.cli": ("reproduce",),
    "incipient_slip.experiments.run_plot": ("run",),
    "incipient_slip.nodes.device_tools": ("robot", "rig"),
    "incipient_slip.nodes.calibrate": ("calibrate",),
    "incipient_slip.nodes.foxglove_bridge": ("view",),
}
COMMAND_MODULES = tuple(COMMANDS)


def modules_for(argv: list[str], modules: tuple[str, ...] = COMMAND_MODULES) -> tuple[str, ...]:
    """The modules `slip argv` needs: the one registering its command word, else all."""
    word = next((a for a in argv if not a.startswith("-")), None)
    mine = tuple(m for m in modules if word in COMMANDS.get(m, ()))
    return mine or modules


def build_parser(modules: tuple[str, ...] = COMMAND_MODULES) -> argparse.ArgumentParser:
    """Return the `slip` parser with the commands of `modules`."""
    parser = argparse.ArgumentParser(
        prog="slip",
        description="Incipient slip detection by vibration injection: tools for the node graph, "
        "the simulated rig, the slip models and the paper's experiments.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for entry in modules:
        module_name, _, function = entry.partition(":")
        getattr(importlib.import_module(module_name), function or "register")(subparsers)
    return parser


def _where(args: argparse.Namespace) -> str:
    """Return the command line's command words, e.g. 'slip reproduce stabilization'."""
    words = [args.command] + [getattr(args, a) for a in ("tool", "experiment")
                              if isinstance(getattr(args, a, None), str)]
    return " ".join(["slip", *words])


def main(argv: list[str] | None = None, modules: tuple[str, ...] = COMMAND_MODULES) -> int:
    """Runs `slip` (or, with `modules`, a subset of its commands); returns the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser(modules_for(argv, modules)).parse_args(argv)
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()            # here, not at exit: a closed pipe is then ours to handle
        return code
    except UsageError as exc:
        print(f"{_where(args)}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except ModuleNotFoundError as exc:      # an optional extra not installed: say which
        line = extras.hint(exc)
        if line is None:
            raise
        print(f"{_where(args)}: error: {line}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # `slip ... | head`: the reader went away; end quietly, like any Unix tool. (Not by
        # SIGPIPE's default action: a node killed by it leaves its announcement behind; the
        # graph tools' nodes end themselves cleanly on it, topic_nodes.say.) Only when stdout is
        # a pipe: a broken socket to a device is an error to show.
        if not stat.S_ISFIFO(os.fstat(sys.stdout.fileno()).st_mode):
            raise
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as exc:                 # after BrokenPipeError, one of its kind
        if not out_of_space(exc):
            raise
        print(f"{_where(args)}: error: {output_error(exc)}; free some space (runs/cache and old "
              "data sets under runs/ are safe to delete) and run it again", file=sys.stderr)
        return EXIT_FAILURE


if __name__ == "__main__":
    sys.exit(main())
