"""Topology: which node of a launch writes and reads which topic, from the nodes' declarations.

The launcher imports each node's module (it does not start it), takes the `Node` subclass
defined there, reads its `INPUTS`/`OUTPUTS` and applies the node's remaps. From that table it
prints the graph (`launch FILE --print`), warns about a topic read but written by no node, and
tells each node (in `$SLIP_READERS`) the readers of its outputs, which `Node.wait_for_readers`
waits for, and (in `$SLIP_WRITERS`) the writers of its inputs, the only publishers it accepts
them from. A tool that reads or writes whatever the graph holds declares `ANY_TOPIC` ("*"):
the recorder and the monitor read every topic, replay writes every topic (what its file holds
is known only when it runs), so replay waits for every reader of the launch.
"""
from __future__ import annotations

import importlib
import json
import importlib.util
import sys
from dataclasses import dataclass, field

from incipient_slip.graph.launch.parse import LaunchError
from incipient_slip.graph.runtime import ANY_TOPIC, Node
from incipient_slip.messages import Heartbeat

HEARTBEAT_TOPIC = Heartbeat.TOPIC
# {topic: type name} of every typed topic of the launch, told to each node that reads every
# topic (the viewer bridge advertises them all before the sources start)
TOPICS_ENV = "SLIP_TOPICS"

__all__ = ["NodeTopics", "Topology", "node_class", "TOPICS_ENV", "topics_from_env"]

_loaded: dict[str, object] = {}


def _module(target: str):
    """The module of a node: a dotted module name or a .py path (imported once, not run)."""
    if target in _loaded:
        return _loaded[target]
    if target.endswith(".py"):
        name = "_launch_node_" + "".join(c if c.isalnum() else "_" for c in target)
        spec = importlib.util.spec_from_file_location(name, target)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    else:
        module = importlib.import_module(target)
    _loaded[target] = module
    return module


def node_class(target: str) -> type[Node] | None:
    """The Node subclass defined in the module `target`; None when there is not exactly one."""
    try:
        module = _module(target)
    except Exception as exc:   # a node module that does not import would fail to start anyway
        raise LaunchError(f"cannot import node module {target}: {type(exc).__name__}: {exc}") from None
    found = [obj for obj in vars(module).values()
             if isinstance(obj, type) and issubclass(obj, Node) and obj is not Node
             and obj.__module__ == module.__name__]
    return found[0] if len(found) == 1 else None


@dataclass
class NodeTopics:
    """The topics of one node after its remaps ({topic: type name}); None: not declared."""

    name: str
    inputs: dict[str, str] | None
    outputs: dict[str, str] | None
    optional_inputs: frozenset[str] = frozenset()

    @classmethod
    def of(cls, name: str, klass: type[Node] | None, remaps: dict[str, str]) -> "NodeTopics":
        def after_remaps(declared):
            if declared is None:
                return None
            return {remaps.get(t, t): (getattr(c, "__name__", "any") if t != ANY_TOPIC else "any")
                    for t, c in declared.items()}
        if klass is None:
            return cls(name, None, None)
        return cls(name, after_remaps(klass.INPUTS), after_remaps(klass.OUTPUTS),
                   frozenset(remaps.get(t, t) for t in klass.OPTIONAL_INPUTS))


@dataclass
class Topology:
    """Writers and readers of every topic of a launch."""

    nodes: list[NodeTopics]
    writers: dict[str, list[str]] = field(default_factory=dict)
    readers: dict[str, list[str]] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)

    def __post_init__(self):
        for side, table in (("outputs", self.writers), ("inputs", self.readers)):
            for node in self.nodes:
                for topic, type_name in (getattr(node, side) or {}).items():
                    table.setdefault(topic, []).append(node.name)
                    if topic != ANY_TOPIC and type_name != "any":
                        self.types.setdefault(topic, type_name)

    def topics(self) -> list[str]:
        """Every named topic of the launch, sorted."""
        return sorted((set(self.writers) | set(self.readers)) - {ANY_TOPIC})

    def writers_of(self, topic: str) -> list[str]:
        return self.writers.get(topic, []) + self.writers.get(ANY_TOPIC, [])

    def readers_of(self, topic: str) -> list[str]:
        return self.readers.get(topic, []) + self.readers.get(ANY_TOPIC, [])

    def node(self, name: str) -> NodeTopics:
        return next(n for n in self.nodes if n.name == name)

    def readers_of_node(self, name: str) -> dict[str, list[str]]:
        """{output topic of node `name`: the other nodes reading it} (what it waits for)."""
        node = next(n for n in self.nodes if n.name == name)
        outputs = node.outputs or {}
        topics = self.topics() if ANY_TOPIC in outputs else [t for t in outputs if t != ANY_TOPIC]
        out = {}
        for topic in topics:
            readers = [r for r in self.readers_of(topic) if r != name]
            if readers:
                out[topic] = readers
        if ANY_TOPIC in outputs:      # what it writes is known only at run time: every reader
            readers = [r for r in self.readers.get(ANY_TOPIC, []) if r != name]
            if readers:
                out[ANY_TOPIC] = readers
        return out

    def writers_of_node_inputs(self, name: str) -> dict[str, list[str]]:
        """{input topic of node `name`: the nodes of this launch that write it}: the only
        publishers it accepts those topics from (`$SLIP_WRITERS`). Empty for a node that reads
        every topic (a recorder records what comes) or declares no inputs; a topic no node of
        the launch writes (an operator's command) and `/heartbeat` (every node's) are left out."""
        node = next(n for n in self.nodes if n.name == name)
        inputs = node.inputs or {}
        if ANY_TOPIC in inputs:
            return {}
        return {t: self.writers_of(t) for t in inputs if t != HEARTBEAT_TOPIC and self.writers_of(t)}

    def permissions(self) -> dict[str, dict[str, list[str]]]:
        """{node name: {"publish": topics, "subscribe": topics}} for the permissions file
        (security.write_permissions): each node its outputs and inputs ("*" for every topic, and
        for a node that declares none); the `slip` tools' key reads every topic, with `--force`
        it may also write the topics this launch reads and no node writes (an operator's)."""
        from incipient_slip.graph.security import FORCE_IDENTITY, TOOL_IDENTITY
        out = {}
        for node in self.nodes:
            out[node.name] = {side: sorted(getattr(node, attr)) if getattr(node, attr) is not None else [ANY_TOPIC]
                              for side, attr in (("publish", "outputs"), ("subscribe", "inputs"))}
        unwritten = [t for t in self.topics() if self.readers.get(t) and not self.writers_of(t)]
        out[TOOL_IDENTITY] = {"publish": [], "subscribe": [ANY_TOPIC]}
        out[FORCE_IDENTITY] = {"publish": unwritten, "subscribe": [ANY_TOPIC]}
        return out

    def typed_topics(self) -> dict[str, str]:
        """{topic: type name} of every topic of the launch whose type a node declares, and
        `/heartbeat` (every node's)."""
        return {**{t: self.types[t] for t in self.topics() if t in self.types},
                HEARTBEAT_TOPIC: Heartbeat.__name__}

    def warnings(self) -> list[str]:
        """A line for each topic read by a node but written by none, or declared with two types,
        and for each node whose topics are not declared."""
        lines = []
        optional = {(n.name, t) for n in self.nodes for t in n.optional_inputs}
        for topic in self.topics():
            needing = [r for r in self.readers.get(topic, []) if (r, topic) not in optional]
            if needing and not self.writers_of(topic):
                lines.append(f"topic {topic} is read by {', '.join(needing)} but no "
                             f"node of this launch writes it")
        declared: dict[str, dict[str, list[str]]] = {}    # topic -> type -> "node reads/writes"
        for node in self.nodes:
            for side, role in (("outputs", "writes"), ("inputs", "reads")):
                for topic, type_name in (getattr(node, side) or {}).items():
                    if type_name != "any":
                        declared.setdefault(topic, {}).setdefault(type_name, []).append(
                            f"{node.name} {role}")
        for topic, by_type in sorted(declared.items()):
            if len(by_type) > 1:
                lines.append(f"topic {topic} is declared with {len(by_type)} types: " + "; ".join(
                    f"{t} ({', '.join(who)})" for t, who in by_type.items()))
        for node in self.nodes:
            if node.inputs is None and node.outputs is None:
                lines.append(f"node {node.name} declares no INPUTS/OUTPUTS: its topics are not "
                             f"shown and no publisher waits for it")
        return lines

    def to_plain(self) -> list[dict]:
        """One row per topic: type, writers, readers (what `--print` shows)."""
        return [{"topic": t, "type": self.types.get(t, "any"), "writers": self.writers_of(t),
                 "readers": self.readers_of(t)} for t in self.topics()]


def topics_from_env(environ) -> dict[str, str]:
    """`$SLIP_TOPICS` ({topic: type name}); {} when unset or not such a JSON object."""
    try:
        table = json.loads(environ.get(TOPICS_ENV, "{}"))
        return {str(t): str(n) for t, n in table.items()}
    except (ValueError, AttributeError):
        return {}
