"""`slip WORD` loads only the modules of WORD: `slip topic --help` and `slip topic list` never import
the scientific stack (scipy alone was 530 modules and seconds of start-up under load). These are
properties of the import graph, not timings (bench/bench_cli.py measures the start-up times)."""
from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys

import pytest

from incipient_slip import cli

HEAVY = ("scipy", "sklearn", "matplotlib", "distributed", "dask", "tqdm")
# what the help of `slip topic` and `slip node` does not need either
HELP_NEEDS_NONE_OF = HEAVY + ("numpy", "zmq", "msgspec", "msgpack", "yaml", "mcap")

_PROBE = """
import json, sys
from incipient_slip.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in {heavy})))
"""


def _heavy_modules_loaded(argv: list[str], tmp_path) -> list[str]:
    env = dict(os.environ, SLIP_GRAPH_DIR=str(tmp_path / "graph"))
    out = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=set(HEAVY)), *argv], env=env,
                         capture_output=True, text=True, timeout=300, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [["topic", "--help"], ["topic", "list", "--duration", "0.01"],
                                  ["node", "list"], ["bag", "--help"]], ids=" ".join)
def test_graph_commands_do_not_import_the_scientific_stack(argv, tmp_path):
    assert _heavy_modules_loaded(argv, tmp_path) == []


@pytest.mark.parametrize("argv", [["topic", "--help"], ["node", "--help"], ["topic", "pub", "--help"]],
                         ids=" ".join)
def test_topic_and_node_help_import_neither_numpy_nor_zmq(argv, tmp_path):
    env = dict(os.environ, SLIP_GRAPH_DIR=str(tmp_path / "graph"))
    out = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=set(HELP_NEEDS_NONE_OF)), *argv],
                         env=env, capture_output=True, text=True, timeout=300, check=True).stdout
    assert json.loads(out.strip().splitlines()[-1]) == []


def test_slip_help_does_not_import_the_simulator(tmp_path):
    """`slip --help` registers every command; `sim.cli` (slip dataset) once imported the whole
    simulator through the package's __init__ (scipy, numba: 0.8 s). The package loads its
    names on first use."""
    env = dict(os.environ, SLIP_GRAPH_DIR=str(tmp_path / "graph"))
    heavy = {"scipy", "sklearn", "numba", "matplotlib", "distributed", "dask"}
    out = subprocess.run([sys.executable, "-c", _PROBE.format(heavy=heavy), "--help"], env=env,
                         capture_output=True, text=True, timeout=300, check=True).stdout
    assert json.loads(out.strip().splitlines()[-1]) == []
    assert "incipient_slip.sim.rig" not in subprocess.run(
        [sys.executable, "-c", "import sys; from incipient_slip.cli import main\ntry: main(['--help'])\n"
         "except SystemExit: pass\nprint(sorted(sys.modules))"], env=env, capture_output=True, text=True,
        timeout=300, check=True).stdout


def test_the_simulator_s_public_names_load_on_first_use():
    import incipient_slip.sim as sim
    from incipient_slip.sim.rig import Rig
    assert sim.Rig is Rig and set(sim.__all__) <= set(dir(sim))
    with pytest.raises(AttributeError, match="no attribute 'Rigg'"):
        sim.Rigg


def test_each_module_registers_exactly_the_commands_the_table_names():
    # cli.COMMANDS is how `slip WORD` finds the one module to import: it must not drift
    for entry, words in cli.COMMANDS.items():
        parser = argparse.ArgumentParser()
        sub = parser.add_subparsers()
        module, _, function = entry.partition(":")
        getattr(importlib.import_module(module), function or "register")(sub)
        assert tuple(sub.choices) == words, entry


def test_help_and_unknown_words_still_list_every_command(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    for words in cli.COMMANDS.values():
        for word in words:
            assert word in out
    assert cli.modules_for(["nonsense"]) == cli.COMMAND_MODULES
    assert cli.modules_for(["topic", "list"]) == ("incipient_slip.graph.tools:register_topic",)


def _parsers(parser, words=("slip",)):
    """Every parser of the `slip` tree with its command words."""
    yield words, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for word, child in action.choices.items():
                yield from _parsers(child, (*words, word))


def test_every_help_of_the_slip_tree_renders():
    """argparse %-formats help texts: a bare '%' in one ('top-10 % RMSE') made `slip reproduce
    --help` a traceback. Every command's help, and every help line it lists, must render."""
    seen = []
    for words, parser in _parsers(cli.build_parser()):
        assert parser.format_help(), words
        seen.append(" ".join(words))
    assert {"slip reproduce", "slip reproduce estimation", "slip bag export", "slip topic pub"} <= set(seen)
