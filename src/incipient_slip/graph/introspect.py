"""`slip node list|info`, `slip param list|get|dump`, `slip topic info` and `slip topic pub`: the
ROS 2 habits, over discovery.

All but `topic pub` read the nodes' announcement files (graph/discovery.py): who runs, what each
publishes and subscribes, and each node's parameters as resolved at its start (defaults < launch
file < command line; read-only: a running node's parameters cannot be set). `topic pub` builds one message from YAML, validated by the messages
contract (field names, types, bounds, array shapes), and publishes it from a small node once the
topic's live readers have subscribed. Commands are refused (`--force` overrides): a message on a
command topic moves hardware or changes the run, and on a graph with real devices any message
can.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

from incipient_slip.errors import UsageError
from incipient_slip.graph import discovery
from incipient_slip.graph.discovery import ANY_TOPIC, ON_DEMAND

# The messages, the runtime, the params module and yaml are imported by the commands that use them,
# not here: registering these commands (`slip topic --help`) must not load numpy or zmq.

__all__ = ["cmd_node_list", "cmd_node_info", "cmd_param_list", "cmd_param_get", "cmd_param_dump",
           "cmd_topic_info", "cmd_topic_pub", "command_topics", "DEVICE_NODES"]

# nodes that drive real devices: their presence makes the graph a hardware graph
DEVICE_NODES = frozenset({"ur5", "linear_actuator", "pzt_injector", "biotac_reader", "mocap_bridge"})


def command_topics() -> frozenset[str]:
    """The topics whose readers move the rig or change the run."""
    from incipient_slip.messages import ActuatorCommand, GripCommand, PztCommand, RobotRecover
    return frozenset(t.TOPIC for t in (GripCommand, ActuatorCommand, PztCommand, RobotRecover))


def _nodes(args) -> list[discovery.NodeInfo]:
    directory = discovery.graph_dir(getattr(args, "graph", None))
    return sorted((i for i in discovery.scan(directory) if i.pid != os.getpid()),
                  key=lambda i: (i.name, i.pid))


def _plain(info: discovery.NodeInfo) -> dict:
    return {"name": info.name, "pid": info.pid, "endpoint": info.endpoint,
            "publishes": info.publishes, "subscribes": info.subscribes}


def cmd_node_list(args) -> int:
    """Prints the running nodes of the graph, one a line (name, pid)."""
    nodes = _nodes(args)
    if args.json:
        print(json.dumps([_plain(i) for i in nodes]))
    elif not nodes:
        print(f"no nodes in graph {discovery.graph_dir(args.graph)}")
    for info in nodes if not args.json else ():
        print(f"{info.name}  (pid {info.pid})")
    return 0


def _named(args) -> list[discovery.NodeInfo]:
    """The running processes of node `args.node` (UsageError when there is none)."""
    found = [i for i in _nodes(args) if i.name == args.node]
    if not found:
        raise UsageError(f"no node {args.node!r} in graph {discovery.graph_dir(args.graph)} "
                         f"(slip node list shows the running ones)")
    return found


def cmd_node_info(args) -> int:
    """Prints one node's pid, endpoint, publications and subscriptions."""
    for info in _named(args):
        if args.json:
            print(json.dumps(_plain(info)))
            continue
        print(f"{info.name}\n  pid: {info.pid}\n  endpoint: {info.endpoint}\n  publishes:")
        for topic, type_name in sorted(info.publishes.items()):
            print(f"    {topic}: {type_name}")
        print("  subscribes:")
        for topic, type_name in sorted(info.subscribes.items()):
            print(f"    {'(every topic)' if topic == ANY_TOPIC else topic}: {type_name}")
    return 0


def cmd_param_list(args) -> int:
    """Prints the names of a running node's parameters, one a line."""
    for info in _named(args):
        print(json.dumps(sorted(info.params)) if args.json else "\n".join(sorted(info.params)))
    return 0


def cmd_param_get(args) -> int:
    """Prints one parameter of a running node, as `name:=VALUE` would give it."""
    found = _named(args)
    for info in found:
        if args.name not in info.params:
            raise UsageError(f"node {info.name} (pid {info.pid}) has no parameter {args.name!r}; "
                             f"its parameters: {', '.join(sorted(info.params)) or '(none)'}")
        value = info.params[args.name]
        from incipient_slip.graph.params import format_value
        text = json.dumps(value) if args.json else format_value(value)
        print(f"{text}  (pid {info.pid})" if len(found) > 1 else text)
    return 0


def cmd_param_dump(args) -> int:
    """Prints every parameter of a running node as YAML (`name: value`), or as one JSON object."""
    import yaml

    for info in _named(args):
        if args.json:
            print(json.dumps({"name": info.name, "pid": info.pid, "params": info.params}))
            continue
        print(f"# {info.name} (pid {info.pid}): parameters as resolved at its start")
        print(yaml.safe_dump(info.params, sort_keys=True, default_flow_style=False).rstrip()
              if info.params else "{}")
    return 0


def cmd_topic_info(args) -> int:
    """Prints a topic's type, its writers and its live readers (a node reading every topic
    counts as a reader; one that reads them on demand, the viewer bridge, is marked so)."""
    nodes = _nodes(args)
    writers = [i for i in nodes if args.topic in i.publishes]
    readers = [i for i in nodes if args.topic in i.subscribes or ANY_TOPIC in i.subscribes]
    on_demand = {i.name for i in readers if i.subscribes.get(ANY_TOPIC) == ON_DEMAND}
    types = {i.publishes[args.topic] for i in writers} | {i.subscribes[args.topic] for i in readers
                                                         if args.topic in i.subscribes}
    from incipient_slip.messages import DEFAULT_TOPICS, MESSAGE_TYPES
    type_name = next((t for t in sorted(types) if t in MESSAGE_TYPES),
                     DEFAULT_TOPICS[args.topic].__name__ if args.topic in DEFAULT_TOPICS else "?")
    row = {"topic": args.topic, "type": type_name, "writers": [i.name for i in writers],
           "readers": [i.name + (" (on demand)" if i.name in on_demand else "") for i in readers]}
    if args.json:
        print(json.dumps(row))
    else:
        print(f"topic: {row['topic']}\ntype: {row['type']}\n"
              f"writers ({len(writers)}): {', '.join(row['writers']) or '-'}\n"
              f"readers ({len(readers)}): {', '.join(row['readers']) or '-'}")
    return 0


def message_from_yaml(topic: str, text: str, type_name: str | None = None):
    """The message `text` (a YAML mapping of field values) describes on `topic`; UsageError
    naming the field and what would be right when the contract refuses it."""
    import yaml

    from incipient_slip.messages import DEFAULT_TOPICS, MESSAGE_TYPES, MessageError
    msg_type = MESSAGE_TYPES.get(type_name) if type_name else DEFAULT_TOPICS.get(topic)
    if msg_type is None:
        raise UsageError(f"{topic}: no message type known for it (not a default topic and no "
                         f"node announces it); known topics: {', '.join(sorted(DEFAULT_TOPICS))}")
    try:
        fields = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        raise UsageError(f"message is not YAML: {exc}") from None
    if not isinstance(fields, dict):
        raise UsageError(f"message must be a YAML mapping of fields, e.g. '{{stick_ratio: 0.3}}'")
    known = set(msg_type.schema()["fields"]) - {"stamp_ns", "seq"}
    unknown = sorted(set(fields) - known)
    if unknown:
        raise UsageError(f"{msg_type.__name__} has no field {', '.join(unknown)}; "
                         f"fields: {', '.join(sorted(known))}")
    try:
        return msg_type(**fields)
    except (MessageError, TypeError, ValueError) as exc:
        raise UsageError(f"{topic} ({msg_type.__name__}): {exc}") from None


def cmd_topic_pub(args) -> int:
    """Publishes one message (or --times N at --rate) on a topic of the running graph."""
    from incipient_slip.graph.runtime import Node
    from incipient_slip.messages import to_plain

    class _OnePublisher(Node):
        """Publishes given messages on one topic (`slip topic pub`)."""

        def __init__(self, msg_type, topic: str, **kwargs):
            super().__init__("slip_topic_pub", heartbeat_s=0, **kwargs)
            self.pub = self.create_publisher(msg_type, topic)   # OUTPUTS undeclared: any topic

    nodes = _nodes(args)
    announced = {i.publishes.get(args.topic) or i.subscribes.get(args.topic) for i in nodes} - {None, "raw"}
    msg = message_from_yaml(args.topic, args.message, next(iter(sorted(announced)), None))
    devices = sorted({i.name for i in nodes} & DEVICE_NODES)
    if not args.force:
        if args.topic in command_topics():
            raise UsageError(f"{args.topic} is a command topic (its readers move the rig or change "
                             f"the run); pass --force if you mean it")
        if devices:
            raise UsageError(f"graph runs real device nodes ({', '.join(devices)}); "
                             f"pass --force to publish on it")
        recording = sorted(i.name for i in nodes if i.subscribes.get(ANY_TOPIC) == "raw")
        if recording:
            raise UsageError(f"{', '.join(recording)} records every message of this graph: a message "
                             f"from slip topic pub would go into the run's recording (another "
                             f"publisher, another clock); pass --force if you mean it")
    # a reader "on demand" (the viewer bridge) subscribes only while its own clients want the topic
    readers = [i.name for i in nodes if args.topic in i.subscribes
               or i.subscribes.get(ANY_TOPIC) not in (None, ON_DEMAND)]
    from incipient_slip.graph.security import FORCE_IDENTITY, TOOL_IDENTITY
    # over tcp the tools' key is read-only (security.py): only --force may write, and only topics
    # the launch reads that no node of it writes (an operator's commands)
    kwargs = {"graph_dir": discovery.graph_dir(args.graph),
              "identity": FORCE_IDENTITY if args.force else TOOL_IDENTITY}
    _check_tool_key(kwargs["graph_dir"], kwargs["identity"], args.topic)
    if not readers and not any(ANY_TOPIC in i.subscribes for i in nodes):
        # a message nobody reads, not even a viewer on demand, goes nowhere: say so, as a failure
        print(f"slip topic pub: no node of the graph ({kwargs['graph_dir']}) reads "
              f"{args.topic} (is the graph running? `slip topic list`, `slip node list`); nothing was sent",
              file=sys.stderr, flush=True)
        return 1
    with _OnePublisher(type(msg), args.topic, **kwargs) as node:
        if readers and not node.pub.wait_for_subscribers(len(readers), args.wait):
            if node.pub.subscriber_count() == 0:      # a message nobody subscribed to goes nowhere
                print(f"slip topic pub: none of the readers of {args.topic} ({', '.join(readers)}) "
                      f"subscribed within {args.wait:g} s, so nothing was sent. A node started by "
                      f"a launch takes {args.topic} only from that launch's writer of it "
                      f"(`slip topic info {args.topic}` names it; docs/graph.md); a slow reader: "
                      f"raise --wait", file=sys.stderr, flush=True)
                return 1
            print(f"slip topic pub: only {node.pub.subscriber_count()} of {len(readers)} readers "
                  f"({', '.join(readers)}) subscribed after {args.wait:g} s; publishing to those",
                  flush=True)
        for i in range(args.times):
            # stamped here (stamp 0 = now, wall clock), so that what is printed is what is sent
            sent = msg if msg.stamp_ns else dataclasses.replace(msg, stamp_ns=time.time_ns())
            seq = node.pub.publish(sent)
            print(f"published {type(msg).__name__} seq {seq} on {args.topic}: "
                  f"{json.dumps(to_plain(dataclasses.replace(sent, seq=seq)), default=str)}", flush=True)
            if i + 1 < args.times:
                time.sleep(1.0 / args.rate)
    return 0


def _check_tool_key(graph_dir, identity: str, topic: str) -> None:
    """Over tcp with a permissions file: UsageError when the tools' key may not publish `topic`
    (every reader would refuse the message)."""
    from incipient_slip.graph import security
    if security.transport() != "tcp":
        return
    ring = security.keyring(security.keystore(graph_dir))
    key = ring.key_of(identity)
    if ring.restricted and (key is None or not ring.may_write(key, topic)):
        hint = ("pass --force to use the tools' other key, which may publish the topics the launch "
                "reads and none of its nodes writes" if identity == security.TOOL_IDENTITY else
                "no node of the launch writes the topics it may publish")
        raise UsageError(f"over tcp the tools' key ({identity}) may not publish {topic} in "
                         f"{ring.store / security.PERMISSIONS_FILE}: every reader would refuse it; {hint}")


def register_topic(tsub, graph, guard) -> None:
    """Adds `info` and `pub` to `slip topic`."""
    p = tsub.add_parser("info", parents=[graph], help="a topic's type, writers and live readers")
    p.add_argument("topic", help="e.g. /slip/estimate")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.set_defaults(func=guard(cmd_topic_info))
    p = tsub.add_parser(
        "pub", parents=[graph], help="publish a message given as YAML (validated by the contract)",
        description="Publishes one message on TOPIC from a YAML mapping of its fields (the rest "
        "keep their defaults; stamp and seq are set on sending), once every live reader has "
        "subscribed. Command topics (grip, actuator and PZT commands, robot recovery: their "
        "readers move the rig or change the run) and any topic of a graph with real device "
        "nodes are refused without --force.")
    p.add_argument("topic", help="e.g. /sim/truth")
    p.add_argument("message", nargs="?", default="", help="YAML, e.g. '{stick_ratio: 0.3, valid: true}'")
    p.add_argument("--times", type=int, default=1, metavar="N", help="publish N times (default 1)")
    p.add_argument("--rate", type=float, default=1.0, metavar="HZ", help="with --times: rate (default 1 Hz)")
    p.add_argument("--wait", type=float, default=3.0, metavar="S",
                   help="wait at most S s for the readers to subscribe (default 3)")
    p.add_argument("--force", action="store_true", help="publish on a command topic or on hardware")
    p.set_defaults(func=guard(cmd_topic_pub))


def register_node(subparsers, graph, guard) -> None:
    """Adds `slip node list|info`."""
    node = subparsers.add_parser("node", help="the nodes of a running graph")
    nsub = node.add_subparsers(dest="tool", metavar="TOOL", required=True)
    p = nsub.add_parser("list", parents=[graph], help="running nodes (name, pid)")
    p.add_argument("--json", action="store_true", help="one JSON list with each node's topics")
    p.set_defaults(func=guard(cmd_node_list))
    p = nsub.add_parser("info", parents=[graph], help="a node's pid, endpoint, publications "
                        "and subscriptions")
    p.add_argument("node", help="node name, e.g. estimator")
    p.add_argument("--json", action="store_true", help="one JSON object per process of that name")
    p.set_defaults(func=guard(cmd_node_info))


def register_param(subparsers, graph, guard) -> None:
    """Adds `slip param list|get|dump` (read-only: there is no `set`)."""
    param = subparsers.add_parser(
        "param", help="the parameters of a running node (read-only)",
        description="A running node's parameters as it resolved them at its start (its defaults < "
        "the launch file < its command line), read from its announcement in the graph directory. "
        "Read-only: a node reads its parameters once; change them in the launch file or on the "
        "command line and restart it.")
    psub = param.add_subparsers(dest="tool", metavar="TOOL", required=True)
    named = argparse.ArgumentParser(add_help=False, parents=[graph])
    named.add_argument("node", help="node name, e.g. grip_controller")
    for verb, handler, summary, description, as_json in (
            ("list", cmd_param_list, "a node's parameter names", None,
             "one JSON list per process of that name"),
            ("get", cmd_param_get, "one parameter's value", "Prints the value of parameter NAME of "
             "node NODE, as `NAME:=VALUE` on a node's command line would give it.", "the value as JSON"),
            ("dump", cmd_param_dump, "all of a node's parameters as YAML", "Prints every parameter "
             "of node NODE as YAML (name: value, sorted by name) after a comment line naming the "
             "node and its pid.", "one JSON object per process of that name")):
        p = psub.add_parser(verb, parents=[named], help=summary, description=description)
        if verb == "get":
            p.add_argument("name", help="parameter name, e.g. s_d")
        p.add_argument("--json", action="store_true", help=as_json)
        p.set_defaults(func=guard(handler))
