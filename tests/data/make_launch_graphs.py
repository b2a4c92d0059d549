"""Writes tests/data/launch_graphs.json: the graph (`launch FILE --print`) of each shipped launch
file for each rig and method, with this checkout's paths and interpreter replaced and each node's
`source` (file:line) left out, so that moving a node between files (an include) is no change.

    .venv/bin/python tests/data/make_launch_graphs.py tests/data/launch_graphs.json

tests/control/test_launch_files.py compares the launch files with it: run this only when a graph
is meant to change, and say so in the commit."""
from __future__ import annotations

import json
import sys
from pathlib import Path

from incipient_slip.graph.launch import load

REPO = Path(__file__).resolve().parents[2]
CASES = ([("stabilize.yaml", {"rig": rig, "method": m}) for rig in ("sim", "replay", "emulated", "hardware")
          for m in ("injection", "vibrotactile", "e19", "none")]
         + [("collect.yaml", {"rig": rig, "injection": i}) for rig in ("sim", "emulated", "hardware")
            for i in ("true", "false")]
         + [("identify.yaml", {"rig": rig}) for rig in ("sim", "emulated", "hardware")])


def normalized(value):
    if isinstance(value, dict):
        return {k: normalized(v) for k, v in value.items() if k != "source"}
    if isinstance(value, list):
        return [normalized(v) for v in value]
    if isinstance(value, str):
        return value.replace(sys.executable, "<python>").replace(str(REPO), "<repo>")
    return value


def graphs() -> dict:
    return {f"{name} " + " ".join(f"{k}:={v}" for k, v in args.items()):
            normalized(load(REPO / "launch" / name, args).to_plain()) for name, args in CASES}


if __name__ == "__main__":
    Path(sys.argv[1]).write_text(json.dumps(graphs(), indent=1, sort_keys=True) + "\n")
