"""Fixtures for the models tests: tiny data sets in the documented format (see fakedata.py)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from fakedata import write_fake_dataset  # noqa: E402


@pytest.fixture(scope="session")
def fake_injection_dir(tmp_path_factory):
    return write_fake_dataset(tmp_path_factory.mktemp("fake_inj"), n_series=20, injection=True)


@pytest.fixture(scope="session")
def fake_no_injection_dir(tmp_path_factory):
    return write_fake_dataset(tmp_path_factory.mktemp("fake_noinj"), n_series=20, injection=False)
