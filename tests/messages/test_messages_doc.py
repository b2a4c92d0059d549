"""docs/messages.md is what the generator writes, and what it says about versions and discovery
holds."""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path

import pytest

from incipient_slip.graph import discovery
from incipient_slip.graph.messages_doc import ANNOUNCEMENT_KEYS, REGENERATE, main, render
from incipient_slip.messages import MESSAGE_TYPES

PAGE = Path(__file__).resolve().parents[2] / "docs" / "messages.md"

# Each type's version with a fingerprint of its declarations (notes and descriptions excluded).
# A failure here means the wire contract of a type changed: bump its SCHEMA_VERSION (see
# docs/messages.md, "Schema versions"), then update its pin.
PINS = {
    "BiotacPac": (1, "312e7b2e4856"),
    "BiotacSlow": (1, "27e75fadd27e"),
    "BiotacStatus": (1, "6693d8fc5b77"),
    "BiotacTare": (1, "fefa6c13e29d"),
    "PztCommand": (1, "3bf38aa7b023"),
    "PztState": (1, "420c26496bf8"),
    "PztOutput": (1, "1311694450e4"),
    "ObjectPose": (1, "8a21f7fa9c0c"),
    "ActuatorCommand": (2, "7fcdcd89fede"),
    "ActuatorState": (2, "eddf494e702d"),
    "GripCommand": (2, "7e90d5b396bf"),
    "RobotState": (2, "eca2e1a20c0a"),
    "RobotRecover": (1, "1eed3d56f1d3"),
    "SlipEstimate": (2, "1102b9bbd25c"),
    "SimTruth": (1, "ab56228d9d3a"),
    "RunEvent": (1, "9d9261d74f5d"),
    "Heartbeat": (1, "0718bc1c3b07"),
}


def fingerprint(cls) -> str:
    desc = cls.schema()
    fields = {name: {k: v for k, v in spec.items() if k != "note"} for name, spec in desc["fields"].items()}
    text = json.dumps([desc["type"], desc["encoding"], fields], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def test_page_is_what_the_generator_writes():
    assert PAGE.read_text() == render(), f"docs/messages.md is stale; run: {REGENERATE}"


def test_check_mode_reports_a_stale_page(tmp_path, capsys):
    page = tmp_path / "messages.md"
    page.write_text("old\n")
    assert main([str(page), "--check"]) == 1
    assert "stale" in capsys.readouterr().err
    assert main([str(page)]) == 0 and page.read_text() == render()
    assert main([str(page), "--check"]) == 0


@pytest.mark.parametrize("name", sorted(MESSAGE_TYPES))
def test_a_changed_declaration_comes_with_a_new_schema_version(name):
    cls = MESSAGE_TYPES[name]
    assert (cls.SCHEMA_VERSION, fingerprint(cls)) == PINS[name], (
        f"{name}'s wire contract changed: bump its SCHEMA_VERSION and update PINS")


def test_announcement_files_hold_the_documented_keys(tmp_path):
    info = discovery.NodeInfo("est/imator", 4242, "ipc:///x.sock", {"/a": "BiotacPac"}, {}, 7)
    path = discovery.announce(tmp_path, info)
    assert path.name == "est_imator-4242" + discovery.SUFFIX
    assert tuple(json.loads(path.read_text())) == ANNOUNCEMENT_KEYS


@pytest.fixture
def clean_env(monkeypatch, tmp_path):
    for name in (discovery.GRAPH_DIR_ENV, discovery.GRAPH_ENV, "XDG_RUNTIME_DIR", "TEMP", "TMP"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)      # gettempdir() caches its first answer
    return tmp_path


def test_graph_directory_rules_as_documented(clean_env, monkeypatch):
    tmp = clean_env
    uid = os.getuid()
    assert discovery.graph_dir(create=False) == tmp / f"incipient-slip-{uid}" / "default"
    monkeypatch.setenv(discovery.GRAPH_ENV, "second")
    assert discovery.graph_dir(create=False) == tmp / f"incipient-slip-{uid}" / "second"
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp / "missing"))       # not a directory: ignored
    assert discovery.graph_dir(create=False) == tmp / f"incipient-slip-{uid}" / "second"
    (tmp / "xdg").mkdir()
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp / "xdg"))
    assert discovery.graph_dir(create=False) == tmp / "xdg" / "incipient-slip" / "second"
    monkeypatch.setenv(discovery.GRAPH_DIR_ENV, str(tmp / "explicit"))
    assert discovery.graph_dir(create=False) == tmp / "explicit"


def test_graph_directory_is_private_and_names_are_checked(clean_env, monkeypatch):
    path = discovery.graph_dir()
    assert path.is_dir() and (path.stat().st_mode & 0o777) == 0o700
    for bad in ("a+b", "..", "a/b"):
        monkeypatch.setenv(discovery.GRAPH_ENV, bad)
        with pytest.raises(ValueError, match="graph name"):
            discovery.graph_dir(create=False)
