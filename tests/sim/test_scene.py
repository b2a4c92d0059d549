"""Scenes: effects, prerequisites and unknown keys are checked with messages that name the thing."""
import pytest

from incipient_slip.sim import SceneError, load_scene
from incipient_slip.sim.scene import EFFECTS, scene_from_dict


@pytest.mark.parametrize("name", ["paper", "no_injection", "electrodes_only", "mechanics"])
def test_shipped_scenes_load(name):
    scene = load_scene(name)
    assert scene.name == name and scene.effects <= set(EFFECTS)


def test_unknown_scene_key_names_file_and_key(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("effects: [contact]\nfrobnicate: 3\n")
    with pytest.raises(SceneError, match=r"bad\.yaml.*'frobnicate'"):
        load_scene(f)


def test_missing_prerequisite_names_both_effects():
    with pytest.raises(SceneError, match=r"'injection' needs effect 'fingertip_modes'"):
        scene_from_dict({"effects": ["contact", "stick_slip", "injection", "adc"]}, "x.yaml")


def test_unknown_effect_is_an_error():
    with pytest.raises(SceneError, match="unknown effect 'telepathy'"):
        scene_from_dict({"effects": ["telepathy"]}, "x.yaml")


def test_unknown_override_names_section_and_key():
    with pytest.raises(SceneError, match=r"overrides\.stick_slip\.spring_stifness"):
        scene_from_dict({"effects": ["contact"], "overrides": {"stick_slip": {"spring_stifness": 1}}}, "x.yaml")


def test_missing_scene_lists_known_scenes():
    with pytest.raises(SceneError, match="known scenes: .*paper"):
        load_scene("no_such_scene")


def test_every_parameter_has_value_unit_and_source():
    scene = load_scene("paper")
    assert scene.units  # filled only from {value, unit, source} leaves (missing ones raise)
    assert scene.units["default.yaml:contact.skin_modulus_mpa"] == "MPa"
