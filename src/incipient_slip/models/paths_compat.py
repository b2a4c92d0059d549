"""Repository directories for the models area (shipped models, run outputs)."""
from __future__ import annotations

from pathlib import Path

from ..paths import model_dir, repo_root  # noqa: F401  (re-exported)


def runs_dir() -> Path:
    """Return runs/ at the repository root (git-ignored outputs of training and studies)."""
    return repo_root() / "runs"
