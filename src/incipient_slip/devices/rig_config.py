"""The real rig's configuration file (config/rig.yaml): one section per device node.

Each device node has a `rig_config` parameter; when it names a file, the node takes the
parameters it was not given explicitly from its own section (`natnet`, `zaber`, `ur5`, ...;
`apply_rig_config`). Precedence: node defaults < rig_config section < launch
file / command line.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from incipient_slip.errors import UsageError
from incipient_slip.graph.params import ParamError, merge_params

__all__ = ["apply_rig_config", "load_document", "load_section"]


def load_document(path: str | Path):
    """The parsed YAML of the rig file `path`; UsageError naming what is wrong."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except OSError as exc:
        raise UsageError(f"rig_config {path}: cannot read it ({exc.strerror})") from None
    except yaml.YAMLError as exc:
        raise UsageError(f"rig_config {path}: not valid YAML ({exc})") from None


def load_section(path: str | Path, section: str) -> dict:
    """The mapping under `section` in the YAML file `path`; UsageError naming what is wrong."""
    path = Path(path)
    doc = load_document(path)
    if not isinstance(doc, dict) or section not in doc:
        have = ", ".join(map(str, doc)) if isinstance(doc, dict) else "(not a mapping)"
        raise UsageError(f"rig_config {path}: no section {section!r} (sections: {have})")
    values = doc[section]
    if not isinstance(values, dict):
        raise UsageError(f"rig_config {path}: section {section!r} is not a mapping of parameters")
    return values


def apply_rig_config(node, section: str, explicit: dict | None) -> None:
    """Fills `node.params` from `section` of the file in its `rig_config` parameter and from the
    calibration file it names (`devices.calibration`), keeping every parameter given explicitly
    (`explicit`); ParamError names the file and the key."""
    from incipient_slip.devices import calibration     # it reads the rig file through this module

    path = node.param("rig_config")
    if not path:
        return
    try:
        values = load_section(path, section)
        values = {**values, **calibration.node_values(path, section, values)}
    except UsageError as exc:
        raise ParamError(str(exc)) from None
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
