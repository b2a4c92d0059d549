"""Where the repository's data directories are: launch files, scenes and shipped models.

The project is installed editable, so the repository root is two levels above this package.
"""
from __future__ import annotations

from pathlib import Path


def repo_root() -> Path:
    """Return the repository root (the directory holding pyproject.toml)."""
    return Path(__file__).resolve().parents[2]


def launch_dir() -> Path:
    """Return the directory of launch YAML files."""
    return repo_root() / "launch"


def scenes_dir() -> Path:
    """Return the directory of simulator scene YAML files."""
    return repo_root() / "scenes"


def model_dir() -> Path:
    """Return the directory of shipped model files."""
    return repo_root() / "models"


def runs_dir() -> Path:
    """Return runs/ at the repository root (git-ignored outputs of runs, training and studies)."""
    return repo_root() / "runs"


def docs_dir() -> Path:
    """Return docs/ at the repository root (the hand-written pages the experiments write into)."""
    return repo_root() / "docs"
