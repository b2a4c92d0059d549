"""The one `Settings` every experiment runs with: budget, seed, where results and docs go."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")
BUDGETS = ("quick", "full")


@dataclass
class Settings:
    """How to run one experiment.

    budget: "quick" (a preview: fewer runs and series, each as long as the full budget's, so the
    outcome agrees with the full run's; docs untouched unless `docs` is given) or "full" (the
    numbers in docs/). Each experiment picks its sizes with
    `pick(quick=..., full=...)`, so both budgets of one quantity sit side by side in its module.
    work: where results.json, logs and data go. docs: the docs directory to write into, or None.
    options: the experiment's own command-line options (from its `add_arguments`).
    """

    budget: str = "quick"
    seed: int = 0
    work: Path = Path("runs/experiment")
    docs: Path | None = None
    jobs: int = field(default_factory=lambda: min(2, os.cpu_count() or 1))
    progress: bool = True
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        if self.budget not in BUDGETS:
            raise ValueError(f"budget must be one of {', '.join(BUDGETS)}, got {self.budget!r}")
        if self.jobs < 1:
            raise ValueError(f"jobs must be >= 1, got {self.jobs}")
        self.work = Path(self.work)
        self.docs = None if self.docs is None else Path(self.docs)

    @property
    def quick(self) -> bool:
        """True on the quick budget."""
        return self.budget == "quick"

    def pick(self, quick: T, full: T) -> T:
        """Return `quick` or `full` by the budget."""
        return quick if self.quick else full

    def option(self, name: str, default: Any = None) -> Any:
        """Return the experiment option `name`, or `default` when it was not given (None)."""
        value = self.options.get(name)
        return default if value is None else value

    @property
    def figures(self) -> Path:
        """Return the directory figures go into: docs/figures, or work/figures without docs."""
        return (self.docs / "figures") if self.docs is not None else self.work / "figures"

    def results_file(self, name: str | None) -> Path:
        """Return where an experiment's results are kept: docs/figures/`name` when docs are
        written and the experiment names such a file, else work/results.json."""
        if name and self.docs is not None:
            return self.docs / "figures" / name
        return self.work / "results.json"
