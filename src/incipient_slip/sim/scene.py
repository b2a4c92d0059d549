"""Scenes: which physical effects a simulated rig computes, and with which parameters.

A scene YAML (``scenes/NAME.yaml``) looks like::

    name: paper
    description: the paper's rig, with PZT injection
    params: default                 # sim/params/default.yaml, or a path to another file
    effects: [contact, stick_slip, fingertip_modes, injection, ...]
    injection_db: 0.0               # optional, PZT intensity I in dB
    materials: [pla, abs]           # optional subset, default all materials of the params
    overrides: {stick_slip: {spring_n_per_mm: 0.2}}   # optional parameter overrides

Effects not listed are not computed and their outputs are None. A listed effect whose
prerequisite is missing, an unknown effect or an unknown key is a SceneError naming the file.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import yaml

from incipient_slip.paths import scenes_dir

PARAMS_DIR = Path(__file__).resolve().parent / "params"

# effect -> effects it needs
EFFECTS: dict[str, tuple[str, ...]] = {
    "contact": (),
    "stick_slip": ("contact",),
    "fingertip_modes": ("contact", "stick_slip"),
    "injection": ("fingertip_modes", "adc"),
    "vibrotactile": ("fingertip_modes", "adc"),
    "ambient_noise": ("adc",),
    "electrodes": ("contact", "stick_slip", "adc"),
    "pdc": ("contact", "adc"),
    "temperature": ("adc",),
    "mocap": ("stick_slip",),
    "adc": (),
}
SCENE_KEYS = {"name", "description", "params", "effects", "injection_db", "materials", "overrides"}


class SceneError(ValueError):
    """A scene or parameter file is invalid; the message names the file and the key."""


@dataclass(frozen=True)
class Scene:
    """A validated scene: its effects, plain parameter values and materials."""

    name: str
    effects: frozenset[str]
    params: dict                      # section -> key -> value (units stripped, see params YAML)
    materials: tuple[str, ...]
    injection_db: float = 0.0
    source: str = ""                  # path of the scene file ("" when built in code)
    yaml_text: str = ""
    description: str = ""
    units: dict = field(default_factory=dict, compare=False)

    def has(self, effect: str) -> bool:
        """Return True when the scene computes `effect`."""
        return effect in self.effects

    def material(self, name: str = "") -> str:
        """`name` if the scene has that material, its first one when `name` is empty; SceneError
        listing the scene's materials otherwise."""
        if not name:
            return self.materials[0]
        if name not in self.materials:
            raise SceneError(f"material {name!r} is not in scene {self.name!r} ({', '.join(self.materials)})")
        return name


def _strip(node, where: str, units: dict):
    """Return the parameter tree with each {value, unit, source} leaf replaced by its value."""
    if isinstance(node, dict) and "value" in node:
        missing = {"value", "unit", "source"} - set(node)
        if missing:
            raise SceneError(f"{where}: parameter lacks {sorted(missing)} (need value, unit, source)")
        units[where] = node["unit"]
        return node["value"]
    if isinstance(node, dict):
        return {k: _strip(v, f"{where}.{k}", units) for k, v in node.items()}
    raise SceneError(f"{where}: expected a mapping or {{value, unit, source}}, got {node!r}")


def load_params(name_or_path: str | Path = "default") -> tuple[dict, dict, str]:
    """Return (values, units, path) of a parameter YAML, by name in sim/params or by path."""
    path = Path(name_or_path)
    if not path.suffix:
        path = PARAMS_DIR / f"{name_or_path}.yaml"
    if not path.is_file():
        raise SceneError(f"parameter file not found: {path}")
    raw = yaml.safe_load(path.read_text())
    units: dict = {}
    values = {k: _strip(v, f"{path.name}:{k}", units) for k, v in raw.items()}
    return values, units, str(path)


def load_overlay(path: str | Path) -> dict:
    """Return a params overlay (`slip` identification's output, docs/identification.md): sections of
    {value, unit, source, interval} entries plus its provenance; SceneError names a bad one."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"params overlay not found: {path}")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise SceneError(f"{path}: not valid YAML: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("provenance"), dict):
        raise SceneError(f"{path}: not a params overlay (no 'provenance' mapping; "
                         "write one with launch identify.yaml)")
    return doc


def overlay_entries(doc: dict, where: str = "overlay") -> dict[tuple, dict]:
    """Return {(section, key) or ("materials", material, key): entry} of an overlay."""
    out = {}
    for section, entries in doc.items():
        if section == "provenance":
            continue
        if not isinstance(entries, dict):
            raise SceneError(f"{where}: {section} must be a mapping")
        for key, entry in entries.items():
            if section == "materials":
                if not isinstance(entry, dict):
                    raise SceneError(f"{where}: materials.{key} must be a mapping")
                for mkey, mentry in entry.items():
                    out[(section, key, mkey)] = mentry
            else:
                out[(section, key)] = entry
    for name, entry in out.items():
        if not isinstance(entry, dict) or not {"value", "unit", "source"} <= set(entry):
            raise SceneError(f"{where}: {'.'.join(name)} needs value, unit and source")
        v = entry["value"]
        if not (isinstance(v, (int, float)) and math.isfinite(v)):
            raise SceneError(f"{where}: {'.'.join(name)} = {v!r} is not a finite number")
        _check_interval(f"{where}: {'.'.join(name)}", entry)
    return out


# units of quantities that are positive (stiffnesses, gains, forces; and a material's identified
# mu): a value or an interval end at or below 0 would simulate an impossible rig (a zero stiffness
# divides by zero). A lag (s) may be 0: a slide in the period of the step
POSITIVE_UNITS = ("N/mm", "N/kPa", "N")


def _check_interval(what: str, entry: dict) -> None:
    """An entry's value, and its interval when it has one ([low, high], finite, low <= value <=
    high; validation runs the rig at each end), positive where its unit says so."""
    v, interval = entry["value"], entry.get("interval")
    positive = entry["unit"] in POSITIVE_UNITS or what.endswith(".mu_identified")   # a friction coefficient too
    if positive and v <= 0:
        raise SceneError(f"{what} = {v!r} {entry['unit']}: must be > 0")
    if interval is None:
        return
    if not (isinstance(interval, (list, tuple)) and len(interval) == 2
            and all(isinstance(x, (int, float)) and math.isfinite(x) for x in interval)):
        raise SceneError(f"{what}: interval {interval!r} is not two finite numbers [low, high] "
                         "(an unbounded quantity has no interval: remove it)")
    low, high = interval
    if not low <= v <= high:
        raise SceneError(f"{what}: interval [{low}, {high}] does not hold its value {v}")
    if positive and low <= 0:
        raise SceneError(f"{what}: interval [{low}, {high}] {entry['unit']} reaches {low} (must be > 0)")


def apply_overlay(params: dict, doc: dict, where: str = "overlay", values: dict | None = None) -> dict:
    """Return params with the overlay's values (or `values`, {name tuple: value}, in their place);
    an overlay names only known parameters, plus a material's measured `mu_identified`."""
    overrides: dict = {}
    for name, entry in overlay_entries(doc, where).items():
        value = float((values or {}).get(name, entry["value"]))
        if name[0] == "materials":
            _, material, key = name
            known = params["materials"].get(material)
            if known is not None and key not in known and key != "mu_identified":
                raise SceneError(f"{where}: materials.{material}.{key}: unknown parameter")
            overrides.setdefault("materials", {}).setdefault(material, dict(known or {}))[key] = value
        else:
            overrides.setdefault(name[0], {})[name[1]] = value
    return _apply_overrides(params, overrides, where, label="")


def _apply_overrides(params: dict, overrides: dict, where: str, label: str = "overrides") -> dict:
    """Return params with {section: {key: value}} in place; an unknown section or key names the file."""
    at = f"{label}." if label else ""
    params = copy.deepcopy(params)
    for section, entries in (overrides or {}).items():
        if section not in params:
            raise SceneError(f"{where}: {at}{section}: unknown parameter section "
                             f"(known: {', '.join(sorted(params))})")
        if not isinstance(entries, dict):
            raise SceneError(f"{where}: {at}{section} must be a mapping")
        for key, value in entries.items():
            if key not in params[section]:
                raise SceneError(f"{where}: {at}{section}.{key}: unknown parameter "
                                 f"(known: {', '.join(sorted(params[section]))})")
            params[section][key] = value
    return params


def validate_effects(effects, where: str = "scene") -> frozenset[str]:
    """Return the effects as a frozenset; raise SceneError for unknown or unmet effects."""
    effects = frozenset(effects)
    for effect in sorted(effects):
        if effect not in EFFECTS:
            raise SceneError(f"{where}: unknown effect {effect!r} (known: {', '.join(EFFECTS)})")
        for need in EFFECTS[effect]:
            if need not in effects:
                raise SceneError(f"{where}: effect {effect!r} needs effect {need!r}, which the scene does not list")
    return effects


def with_values(scene: Scene, values: dict) -> Scene:
    """Return the scene with {(section, key): value} replaced in its parameters (KeyError names an unknown one)."""
    params = {k: (dict(v) if isinstance(v, dict) else v) for k, v in scene.params.items()}
    for (section, key), value in values.items():
        if key not in params[section]:
            raise KeyError(f"unknown parameter {section}.{key}")
        params[section][key] = value
    return replace(scene, params=params)


def with_effects(scene: Scene, effects) -> Scene:
    """Return the scene restricted to `effects` (those it has)."""
    keep = validate_effects([e for e in effects if scene.has(e)], scene.source or scene.name)
    return replace(scene, effects=keep)


def scene_from_dict(doc: dict, where: str = "scene", yaml_text: str = "") -> Scene:
    """Return a Scene from a parsed scene document (see module docstring)."""
    if not isinstance(doc, dict):
        raise SceneError(f"{where}: a scene must be a mapping")
    for key in doc:
        if key not in SCENE_KEYS:
            raise SceneError(f"{where}: unknown key {key!r} (known: {', '.join(sorted(SCENE_KEYS))})")
    if "effects" not in doc:
        raise SceneError(f"{where}: missing key 'effects'")
    effects = validate_effects(doc["effects"], where)
    values, units, _ = load_params(doc.get("params", "default"))
    values = _apply_overrides(values, doc.get("overrides"), where)
    all_materials = tuple(values["materials"])
    materials = tuple(doc.get("materials") or all_materials)
    for m in materials:
        if m not in values["materials"]:
            raise SceneError(f"{where}: unknown material {m!r} (known: {', '.join(all_materials)})")
    for section, key, lo, lo_open in (("stick_slip", "rate_strengthening", 0.0, True),
                                       ("stick_slip", "creep_reference_velocity_mm_s", 0.0, True),
                                       ("stick_slip", "restick_velocity_mm_s", 0.0, True),
                                       ("stick_slip", "friction_limit_lag_s", 0.0, False),
                                       ("stick_slip", "spring_n_per_mm", 0.0, True),
                                       ("pre_slip", "bulk_shear_n_per_mm", 0.0, True),
                                       ("contact", "contact_saturation_radius_mm", 0.0, True),
                                       ("electrodes", "drift_time_s", 0.0, True)):
        v = values[section][key]
        if not (isinstance(v, (int, float)) and v == v and abs(v) != float("inf")) or v < lo or (lo_open and v == lo):
            raise SceneError(f"{where}: {section}.{key} = {v} must be {'>' if lo_open else '>='} {lo} and finite")
    return Scene(name=str(doc.get("name", Path(where).stem)), effects=effects, params=values,
                 materials=materials, injection_db=float(doc.get("injection_db", 0.0)),
                 source=where, yaml_text=yaml_text, description=str(doc.get("description", "")),
                 units=units)


def load_scene(name_or_path: str | Path, overlay: str | Path | None = None) -> Scene:
    """Return the Scene named `name_or_path` (scenes/NAME.yaml) or read from that path; with
    `overlay`, an identified rig's params overlay applied on top (docs/identification.md)."""
    scene = _load_scene(name_or_path)
    if overlay:
        import dataclasses
        scene = dataclasses.replace(scene, params=apply_overlay(scene.params, load_overlay(overlay), str(overlay)))
    return scene


def _load_scene(name_or_path: str | Path) -> Scene:
    path = Path(name_or_path)
    if not path.suffix:
        path = scenes_dir() / f"{name_or_path}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in scenes_dir().glob("*.yaml"))
        raise SceneError(f"scene not found: {name_or_path} (looked for {path}; known scenes: {', '.join(known)})")
    text = path.read_text()
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SceneError(f"{path}: not valid YAML: {exc}") from None
    return scene_from_dict(doc, str(path), text)
