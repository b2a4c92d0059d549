"""`launch FILE.yaml [name:=value ...]`: start a graph of nodes from a YAML launch file.

The file format follows ROS 2's YAML launch frontend. A top-level `launch:` list of actions:

    launch:
      # which rig feeds the graph; choices: any other value is refused before anything starts
      - arg: {name: rig, default: sim, choices: [sim, replay, hardware], description: "..."}
      - node:
          exec: estimator            # incipient_slip.nodes.estimator (pkg: graph for the tool
                                     # processes recorder, replay, monitor), a dotted module, or a .py path
          name: estimator            # default: a module's last part, a .py path's stem
                                     # (unique in the launch: a name used twice is refused)
          param: [{name: method, value: "$(var method)"}]
          remap: [{from: /biotac/pac, to: /biotac/pac_raw}]
          required: true             # its exit ends the launch (with its exit code)
          respawn: false             # restart it when it exits (after respawn_delay s)
          gate: false                # true: the nodes after it start once it exited 0; any
                                     # other exit ends the launch with its code (a device check)
          if: "$(var rig) == sim"    # or unless:; also on group and include
      - group: {if: "$(var rig) == hardware", actions: [...]}
      - include: {file: other.yaml, arg: [{name: rig, value: "$(var rig)"}]}

Substitutions in strings: `$(var NAME)`, `$(env NAME [default])`, `$(dirname)` (the launch
file's directory) and `$(eval EXPR)` (literals, comparisons, and/or/not, arithmetic only; never
Python's eval). A condition is `true`/`false` (also 1/0, yes/no) or `A == B` / `A != B`.
A param value that came from a substitution is re-typed as YAML (`"$(var rate)"` -> 100).

Before anything starts, every arg with `choices:` is checked against them (a value outside:
exit 2, one line naming the arg, the value and the choices; an empty choice is explained by the
arg's description), every node's params are checked against its declared ranges (a bad
value: exit 2, one line naming it) and the topics are drawn from the nodes' INPUTS/OUTPUTS
(`--print` lists each topic's writers and readers; a topic read but not written is a warning).
Each publisher is told the readers of its outputs and waits for them by name at start-up.

How a launch ends: a required node that exits ends it with that node's code (0 when it finished
cleanly, e.g. a supervisor at the end of a run; 2 when it refused its input, a param or a file;
128+N when signal N killed it, or stopped it cleanly when sent from outside the launch: 143 for
SIGTERM, an interrupted run), its last line repeated last. A node that exits 2 is not respawned;
if other nodes wait for it as a reader, it ends the launch with 2 as a required node would.
Ctrl-C or SIGTERM stops every node (SIGTERM in reverse start order, then SIGKILL after the grace
period; a second Ctrl-C kills at once) and exits 130 (143 for SIGTERM). A stop that needed SIGKILL
exits 3 (a fault), unless a required node had already exited non-zero. When every node has exited
by itself the launch exits 0, or with the first non-zero code.
"""
# The package in four steps: parse (YAML -> actions with lines), substitute ($(...), conditions),
# resolve (args, groups, includes, node specs, param checks; topology: who writes and reads what),
# supervise (processes, required/respawn, signals, exit codes). This module is the command line.
from __future__ import annotations

import argparse
import sys

import yaml

from incipient_slip.errors import EXIT_USAGE
from incipient_slip.graph import discovery, security
from incipient_slip.graph.launch.parse import LaunchError, parse_document
from incipient_slip.graph.launch.resolve import (LaunchDescription, NodeSpec, check_node_inputs, find_launch_file,
                                                 load, load_text)
from incipient_slip.graph.launch.supervise import GRACE_S, Launcher

__all__ = ["LaunchError", "NodeSpec", "LaunchDescription", "parse_document", "load", "load_text",
           "find_launch_file", "Launcher", "main"]


def _split_cli_args(tokens: list[str]) -> dict[str, str]:
    out = {}
    for token in tokens:
        if ":=" not in token:
            raise LaunchError(f"argument {token!r} is not name:=value")
        name, value = token.split(":=", 1)
        out[name] = value
    return out


def _printed(plain: dict) -> str:
    """The resolved launch as YAML, each topic's writer and reader lists on one line."""
    def dump(part: dict, flow=False) -> str:
        return yaml.safe_dump(part, sort_keys=False, width=120, default_flow_style=None if flow else False)
    return (dump({k: plain[k] for k in ("file", "args")})
            + dump({"topics": plain["topics"]}, flow=True)
            + dump({k: v for k, v in plain.items() if k not in ("file", "args", "topics")}))


def _shown_args(desc: LaunchDescription) -> str:
    """Each launch arg with its value (the default unless given) and the file's description."""
    width = max((len(name) for name in desc.args), default=0)
    lines = []
    for name, value in desc.args.items():
        text = desc.arg_descriptions.get(name, "")
        lines.append(f"{name:<{width}} := {value!s:<12}" + (f"  # {text}" if text else ""))
    return "\n".join(lines) + "\n"


def _dot(desc: LaunchDescription) -> str:
    """The graph in Graphviz: nodes as boxes, topics as ellipses, writer -> topic -> reader."""
    def q(text: str) -> str:
        return '"' + text.replace('"', '\\"') + '"'
    lines = ["digraph launch {", "  rankdir=LR;", "  node [fontname=Helvetica];"]
    lines += [f"  {q(n.name)} [shape=box];" for n in desc.nodes]
    for row in (desc.topology.to_plain() if desc.topology else []):
        topic = row["topic"]
        label = q(f"{topic}\\n{row['type']}")
        lines.append(f"  {q(topic)} [shape=ellipse, label={label}];")
        lines += [f"  {q(w)} -> {q(topic)};" for w in row["writers"]]
        lines += [f"  {q(topic)} -> {q(r)};" for r in row["readers"]]
    return "\n".join(lines + ["}"]) + "\n"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="launch", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Start a graph of nodes from a YAML launch file, each node its own process "
        "with its output prefixed [name].",
        epilog=__doc__.split("\n", 2)[2])
    parser.add_argument("file", help="launch file: a path, or a name in launch/ (e.g. demo.yaml)")
    parser.add_argument("args", nargs="*", metavar="name:=value", help="launch argument values")
    parser.add_argument("--print", action="store_true", dest="print_only",
                        help="print the resolved graph (args, nodes, params, remaps, topics with "
                        "their writers and readers) and exit")
    parser.add_argument("--dot", action="store_true",
                        help="with --print: the graph of nodes and topics as Graphviz "
                        "(launch FILE --print --dot | dot -Tsvg > graph.svg)")
    parser.add_argument("--show-args", action="store_true",
                        help="print each launch arg with its default (or given value) and its "
                        "description, and exit")
    parser.add_argument("--grace", type=float, default=GRACE_S, metavar="S",
                        help=f"seconds from SIGTERM to SIGKILL at shutdown (default {GRACE_S:g})")
    parser.add_argument("--graph", metavar="NAME", help="graph name (default $SLIP_GRAPH or "
                        "'default'; $SLIP_GRAPH_DIR overrides the directory)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_intermixed_args(argv)
    try:
        if not args.grace >= 0:
            raise LaunchError(f"--grace must be >= 0 s, got {args.grace}")
        desc = load(args.file, _split_cli_args(args.args))
        if args.show_args:
            print(_shown_args(desc), end="")
            return 0
        if args.dot and not args.print_only:
            raise LaunchError("--dot goes with --print (launch FILE --print --dot)")
        if args.print_only:
            print(_dot(desc) if args.dot else _printed(desc.to_plain()), end="")
            return 0
        graph_dir = discovery.graph_dir(args.graph)
        # $SLIP_TRANSPORT, before any node starts (TransportError); over tcp the nodes' keys and
        # the permissions file they enforce (security.py), written from the topology
        if security.transport() == "tcp" and desc.topology is not None:
            security.write_permissions(security.keystore(graph_dir), desc.topology.permissions(),
                                       f"launch {desc.file}")
        check_node_inputs(desc)    # the files params name (an overlay), likewise
    except (LaunchError, discovery.GraphNameError) as exc:
        print(f"launch: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return Launcher(desc, args.grace, graph_dir).run()


if __name__ == "__main__":
    sys.exit(main())
