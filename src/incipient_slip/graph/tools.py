"""`slip topic list|echo|hz|info|pub`, `slip node list|info` (graph/introspect.py) and `slip bag record|play|info|recover|export`: look at a running graph, record it, replay it.

Each command that touches the graph runs a small node in the foreground (found through the
same discovery as every node: $SLIP_GRAPH_DIR, $SLIP_GRAPH or --graph); Ctrl-C ends it with
exit code 0. Bad input (a missing or corrupt file, a topic without '/', a rate <= 0) is one
line on stderr and exit code 2. See docs/tools.md.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from incipient_slip.errors import UsageError
from incipient_slip.graph import discovery, introspect

# The runtime, the messages and the bag module are imported by the commands that use them:
# registering the commands (`slip topic --help`) must not load numpy or zmq.

__all__ = ["register", "register_topic", "register_bag"]


# --- command handlers ------------------------------------------------------------------------

def _node_argv(**params) -> list[str]:
    from incipient_slip.graph.params import format_value
    return [f"{k}:={format_value(v)}" for k, v in params.items()]


def _graph_kwargs(args) -> dict:
    """The graph directory of --graph / $SLIP_GRAPH_DIR / $SLIP_GRAPH, resolved here so that a bad
    name is this command's one-line error (GraphNameError is a ValueError), not a node's; and
    the tools' identity over tcp (security.py): read-only, or with --force the operator's."""
    from incipient_slip.graph.security import FORCE_IDENTITY, TOOL_IDENTITY
    return {"graph_dir": discovery.graph_dir(getattr(args, "graph", None)),
            "identity": FORCE_IDENTITY if getattr(args, "force", False) else TOOL_IDENTITY}


def _topic(text: str) -> str:
    if not text.startswith("/") or " " in text or "\0" in text:
        raise UsageError(f"topic {text!r} must start with '/' (e.g. /biotac/pac)")
    return text


def _positive(name: str, value, allow_zero: bool = False):
    if value is not None and not (value >= 0 if allow_zero else value > 0):
        raise UsageError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value}")
    return value


def cmd_topic_list(args) -> int:
    from incipient_slip.graph.runtime import run_node
    from incipient_slip.graph.topic_nodes import TopicList
    _positive("--duration", args.duration)
    return run_node(TopicList, _node_argv(duration_s=args.duration, json=args.json),
                    heartbeat_s=0, **_graph_kwargs(args))


def cmd_topic_echo(args) -> int:
    from incipient_slip.graph.runtime import run_node
    from incipient_slip.graph.topic_nodes import TopicEcho
    _positive("--count", args.count, allow_zero=True)
    return run_node(TopicEcho, _node_argv(topic=_topic(args.topic), count=args.count, json=args.json),
                    heartbeat_s=0, **_graph_kwargs(args))


def cmd_topic_hz(args) -> int:
    from incipient_slip.graph.runtime import run_node
    from incipient_slip.graph.topic_nodes import TopicHz
    _positive("--window", args.window)
    _positive("--duration", args.duration, allow_zero=True)
    return run_node(TopicHz, _node_argv(topic=_topic(args.topic), window=args.window,
                                        duration_s=args.duration or 0.0),
                    heartbeat_s=0, **_graph_kwargs(args))


def cmd_bag_record(args) -> int:
    from incipient_slip.graph.recorder import Recorder
    from incipient_slip.graph.runtime import run_node

    out = Path(args.out)
    if not out.parent.is_dir():
        raise UsageError(f"{out}: directory {out.parent} does not exist")
    if out.is_dir():
        raise UsageError(f"{out}: is a directory, expected a file name like run.mcap")
    topics = [_topic(t) for t in args.topics]
    _positive("--max-messages", args.max_messages, allow_zero=True)
    return run_node(Recorder, _node_argv(path=str(out), topics=topics, compression=args.compression,
                                         max_messages=args.max_messages),
                    **_graph_kwargs(args))


def cmd_bag_play(args) -> int:
    from incipient_slip.graph.bag import bag_info
    from incipient_slip.graph.replay import Replay, resolve_bag_path
    from incipient_slip.graph.runtime import run_node

    path = resolve_bag_path(args.bag)
    info = bag_info(path)   # BagError here is a clean exit 2, before any socket exists
    recorded = {t.topic for t in info.topics}
    topics = [_topic(t) for t in args.topics or []]
    missing = [t for t in topics if t not in recorded]
    if missing:
        raise UsageError(f"{path}: no topic {', '.join(missing)}; it has {', '.join(sorted(recorded))}")
    _positive("--rate", args.rate)
    return run_node(Replay, _node_argv(
        path=str(path), rate=args.rate or 1.0, max_speed=args.max_speed, loop=args.loop,
        topics=topics, wait_subscribers=args.wait_subscribers, wait_timeout_s=args.wait_timeout,
        progress=sys.stderr.isatty()), **_graph_kwargs(args))


def cmd_bag_info(args) -> int:
    from incipient_slip.graph.bag import bag_info
    with _bytes_bar(args.bag, "reading") as bar:
        info = bag_info(args.bag, damaged_ok=True, progress=bar.update)
    print(json.dumps(info.to_plain(), indent=1) if args.json else info.format())
    return 0


def _output(path: str, src: str, force: bool) -> Path:
    """`path` checked as a new output file next to `src` (UsageError if it cannot be one)."""
    out = Path(path)
    if out.is_dir():
        raise UsageError(f"{out}: is a directory, expected a file name like out.mcap")
    if not out.parent.is_dir():
        raise UsageError(f"{out}: directory {out.parent} does not exist")
    if out.exists() and Path(src).exists() and out.samefile(src):
        raise UsageError(f"{out}: is the input file; write to another file")
    if out.exists() and not force:
        raise UsageError(f"{out}: exists; pass --force to replace it")
    return out


def _bytes_bar(path, desc: str):
    """A tqdm progress bar over the bytes of `path` (shown only on a terminal)."""
    from tqdm import tqdm

    try:
        total = os.path.getsize(path)
    except OSError:
        total = None
    return tqdm(total=total, unit="B", unit_scale=True, desc=desc, file=sys.stderr, leave=False,
                disable=not sys.stderr.isatty())


def cmd_bag_recover(args) -> int:
    from incipient_slip.graph.bag import recover

    out = _output(args.out, args.bag, args.force)
    with _bytes_bar(args.bag, "recovering") as bar:
        result = recover(args.bag, out, progress=bar.update)
    print(json.dumps(result.to_plain(), indent=1) if args.json else result.format())
    return 0


def cmd_bag_export(args) -> int:
    from tqdm import tqdm

    from incipient_slip.graph.bag import bag_info
    from incipient_slip.graph.bag_export import export_foxglove

    out = _output(args.out, args.bag, args.force)
    total = bag_info(args.bag).message_count   # BagError (exit 2) for a missing/unfinished file
    with tqdm(total=total, unit="msg", desc="exporting", file=sys.stderr, leave=False,
              disable=not sys.stderr.isatty()) as bar:
        report = export_foxglove(args.bag, out, progress=bar.update)
    print(report.format())
    return 0


def _guard(handler):
    """`handler` with bad input turned into one line on stderr and exit code 2."""
    def run(args) -> int:
        try:
            return handler(args)
        except BrokenPipeError:     # not bad input: the reader of stdout went away (cli.main)
            raise
        except Exception as exc:
            from incipient_slip.graph.bag import BagError    # loaded already if it raised one
            if isinstance(exc, (BagError, ValueError, OSError)):
                raise UsageError(str(exc)) from exc
            raise
    return run


# --- registration ----------------------------------------------------------------------------

def register(subparsers) -> None:
    """Adds `slip topic ...`, `slip node ...` and `slip bag ...` to the `slip` command."""
    register_topic(subparsers)
    register_bag(subparsers)


def _graph_option() -> argparse.ArgumentParser:
    graph = argparse.ArgumentParser(add_help=False)
    graph.add_argument("--graph", metavar="NAME", help="graph name (default $SLIP_GRAPH or "
                       "'default'; $SLIP_GRAPH_DIR overrides the directory)")
    return graph


def command_group(subparsers, word: str, **parser_kw):
    """`slip WORD TOOL ...`: the subparsers of WORD's tools (TOOL required)."""
    return subparsers.add_parser(word, **parser_kw).add_subparsers(dest="tool", metavar="TOOL", required=True)


def register_topic(subparsers) -> None:
    """Adds `slip topic ...` and `slip node ...` (light: nothing of numpy or zmq is imported)."""
    graph = _graph_option()
    tsub = command_group(subparsers, "topic", help="look at the topics of a running graph")
    p = tsub.add_parser("list", parents=[graph], help="topics being published now, types and rates")
    p.add_argument("--duration", type=float, default=1.0, metavar="S",
                   help="listen this long to measure rates (default 1 s)")
    p.add_argument("--json", action="store_true", help="print one JSON list")
    p.set_defaults(func=_guard(cmd_topic_list))
    p = tsub.add_parser("echo", parents=[graph], help="print the messages of a topic")
    p.add_argument("topic", help="e.g. /slip/estimate")
    p.add_argument("--count", "-n", type=int, default=0, metavar="N", help="exit after N messages")
    p.add_argument("--json", action="store_true", help="one JSON object per line (NaN as null)")
    p.set_defaults(func=_guard(cmd_topic_echo))
    p = tsub.add_parser("hz", parents=[graph], help="print the rate of a topic every second")
    p.add_argument("topic", help="e.g. /biotac/pac")
    p.add_argument("--window", "-w", type=int, default=100, metavar="N",
                   help="rate over the last N messages (default 100)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="exit after S seconds")
    p.set_defaults(func=_guard(cmd_topic_hz))
    introspect.register_topic(tsub, graph, _guard)
    introspect.register_node(subparsers, graph, _guard)
    introspect.register_param(subparsers, graph, _guard)


def register_bag(subparsers) -> None:
    """Adds `slip bag ...`."""
    from incipient_slip.graph.bag import FLUSH_S

    graph = _graph_option()
    bsub = command_group(
        subparsers, "bag", help="record, play, inspect, recover and export MCAP recordings",
        description="Recordings are MCAP files with one msgpack channel per topic, each with a "
        "JSON schema (PlotJuggler opens them as they are; Foxglove and Lichtblick open the "
        "output of 'slip bag export --foxglove'). See docs/tools.md.")
    p = bsub.add_parser(
        "record", parents=[graph], help="record topics (all if none) to an MCAP file until "
        "Ctrl-C/SIGTERM",
        description="Records every message of TOPICs (all topics if none) as received, to "
        "OUT.mcap, until Ctrl-C or SIGTERM (then the file is finished: summary, footer, fsync). "
        f"Messages are on disk (fsync) at most {FLUSH_S} s after they arrive, so a recorder that "
        "is killed (SIGKILL, power loss) loses at most that last half second: 'slip bag recover' "
        "makes the unfinished file whole.")
    p.add_argument("out", metavar="OUT.mcap", help="file to write (replaced if it exists)")
    p.add_argument("topics", nargs="*", metavar="TOPIC", help="e.g. /biotac/pac (default: all)")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd",
                   help="chunk compression (default zstd)")
    p.add_argument("--max-messages", type=int, default=0, metavar="N",
                   help="stop after N messages (default 0: until Ctrl-C/SIGTERM)")
    p.set_defaults(func=_guard(cmd_bag_record))
    p = bsub.add_parser("play", parents=[graph], help="republish a recording with its original "
                        "seq and stamps",
                        description="Republishes a finished recording with its original seq, "
                        "stamps and bytes, paced by the stamps (or as fast as possible). An "
                        "unfinished file is refused: recover it first.")
    p.add_argument("bag", metavar="IN.mcap")
    speed = p.add_mutually_exclusive_group()
    speed.add_argument("--rate", "-r", type=float, default=None, metavar="R",
                       help="play at R x the recorded speed (default 1)")
    speed.add_argument("--max-speed", action="store_true", help="as fast as possible")
    p.add_argument("--loop", "-l", action="store_true", help="start again at the end, until Ctrl-C")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics "
                   "(default: all but /heartbeat)")
    p.add_argument("--wait-subscribers", type=int, default=1, metavar="N",
                   help="before playing, wait for N subscribers on each topic (default 1; 0: don't)")
    p.add_argument("--wait-timeout", type=float, default=3.0, metavar="S",
                   help="play anyway after S seconds of waiting (default 3)")
    p.add_argument("--force", action="store_true", help="over tcp, publish with the tools' "
                   "--force key (the topics a launch reads and none of its nodes writes); without "
                   "it the tools' key is read-only and readers refuse what it sends")
    p.set_defaults(func=_guard(cmd_bag_play))
    p = bsub.add_parser(
        "info", help="topics, types, counts, duration and rates of a recording; for a damaged "
        "file, what is recoverable",
        description="Prints size, duration and per topic: type, count, rate, stamp span and seq "
        "gaps. A file that was not finished (recorder killed) or is corrupt is not refused: "
        "'status:' says what is wrong and the counts are those 'slip bag recover' would save.")
    p.add_argument("bag", metavar="IN.mcap")
    p.add_argument("--json", action="store_true", help="print one JSON object "
                   "(\"damage\" is null for a finished, intact file)")
    p.set_defaults(func=_guard(cmd_bag_info))
    p = bsub.add_parser(
        "recover", help="turn an unfinished or damaged recording into a finished one",
        description="Reads IN record by record (it need not have a summary or footer), keeps "
        "every message of every complete chunk (bodies byte for byte, receive times, stamps, "
        "seqs) and writes them to a finished OUT. Prints how many messages were recovered per "
        "topic and what was lost: the unfinished last chunk of a killed recorder (at most its "
        f"last {FLUSH_S} s), corrupt chunks (skipped, counted).")
    p.add_argument("bag", metavar="IN.mcap")
    p.add_argument("out", metavar="OUT.mcap")
    p.add_argument("--force", "-f", action="store_true", help="replace OUT if it exists")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object")
    p.set_defaults(func=_guard(cmd_bag_recover))
    p = bsub.add_parser(
        "export", help="write a copy for other viewers (--foxglove: JSON channels for "
        "Foxglove/Lichtblick)",
        description="Foxglove and Lichtblick do not read msgpack. --foxglove writes every topic "
        "as a JSON channel with a jsonschema schema (arrays as lists, NaN as null, integers "
        "beyond 2^53 as decimal strings, plus 'stamp' as {sec, nsec}), and each P_AC topic "
        "also as <topic>/audio of type foxglove.RawAudio (pcm-s16, upsampled to 8800 Hz) for the Audio panel. "
        "Each message is logged at its stamp, as the live view does; seqs are kept.")
    p.add_argument("bag", metavar="IN.mcap", help="a finished recording (recover it first if not)")
    p.add_argument("out", metavar="OUT.mcap")
    p.add_argument("--foxglove", action="store_true", required=True,
                   help="JSON + jsonschema channels and foxglove.RawAudio (the only format so far)")
    p.add_argument("--force", "-f", action="store_true", help="replace OUT if it exists")
    p.set_defaults(func=_guard(cmd_bag_export))


def main(argv: list[str] | None = None) -> int:
    """`python -m incipient_slip.graph.tools topic|bag ...`: these commands without the rest of `slip`."""
    from incipient_slip.cli import main as slip_main
    return slip_main(argv, modules=("incipient_slip.graph.tools:register_topic",
                                    "incipient_slip.graph.tools:register_bag"))


if __name__ == "__main__":
    sys.exit(main())
