"""The real rig's configuration file (config/rig.yaml): one section per device node.

Each device node has a `rig_config` parameter; when it names a file, the node takes the
parameters it was not given explicitly from its own section (`natnet`, `zaber`, `ur5`, ...).
Precedence: node defaults < rig_config section < launch file / command line.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from incipient_slip.graph.params import ParamError, merge_params

__all__ = ["load_section", "apply"]


def load_section(path: str | Path, section: str) -> dict:
    """The mapping under `section` in the YAML file `path`; ParamError naming what is wrong."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except OSError as exc:
        raise ParamError(f"rig_config {path}: cannot read it ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise ParamError(f"rig_config {path}: not valid YAML ({exc})") from None
    if not isinstance(doc, dict) or section not in doc:
        have = ", ".join(map(str, doc)) if isinstance(doc, dict) else "(not a mapping)"
        raise ParamError(f"rig_config {path}: no section {section!r} (sections: {have})")
    values = doc[section]
    if not isinstance(values, dict):
        raise ParamError(f"rig_config {path}: section {section!r} is not a mapping of parameters")
    return values


def apply(node, section: str, explicit: dict | None) -> None:
    """Fills `node.params` from `section` of the file in its `rig_config` parameter, keeping
    every parameter that was given explicitly (`explicit`); ParamError names file and key."""
    path = node.param("rig_config")
    if not path:
        return
    values = load_section(path, section)
    explicit = dict(explicit or {})
    declared: dict = {}
    for klass in reversed(type(node).__mro__):
        declared.update(getattr(klass, "PARAMS", {}) or {})
    try:
        node.params = merge_params(node.name, declared,
                                   {k: v for k, v in values.items() if k not in explicit},
                                   {k: node.params[k] for k in explicit})
    except ParamError as exc:
        raise ParamError(f"rig_config {path} [{section}]: {exc}") from None
