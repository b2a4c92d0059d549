"""The paper's results, one module (or package) per result, all of one shape.

Each experiment module defines

* `NAME`, `HELP` (one line) and `DOC`, the docs page (relative to docs/) its blocks go into;
* `add_arguments(parser)`: its own command-line options (the shared ones are in `Settings`);
* `run(settings) -> results`: does the work within the settings' budget and returns a dict that
  JSON can hold (figures are written while running, into `settings.figures`);
* `render(results) -> {block_name: markdown}`: the generated parts of the docs page, from the
  results alone (so `--render-only` can redo them from results.json). The page's prose is
  hand-written; `docs.write_blocks` puts each block between its markers;
* optionally `RESULTS` (a file name in docs/figures/ that keeps the page's results in the
  repository), `SEED` (its default seed, when not 0) and `check(settings)`, which raises
  UsageError for bad options before anything is printed or started.

An experiment imports no other experiment (tests/repo/test_import_direction.py): what two share
is a module here that is not one (settings, plots, runner, datasets, closed_loop, mechanics_fit).

`slip` imports every experiment module to build its parser, so a module imports the simulator,
scipy or scikit-learn inside `run()` and its helpers, not at the top.

`slip reproduce NAME` runs one (`experiments.cli`); `slip reproduce --list` lists them.
"""
from __future__ import annotations

import importlib
from types import ModuleType

# name -> module; listed in the paper's order
EXPERIMENTS = {
    "calibration": "incipient_slip.experiments.calibration",
    "estimation": "incipient_slip.experiments.estimation",
    "accuracy-vs-time": "incipient_slip.experiments.accuracy_vs_time",
    "models": "incipient_slip.experiments.models",
    "stabilization": "incipient_slip.experiments.stabilization",
    "diagnosis": "incipient_slip.experiments.diagnosis",
    "validation": "incipient_slip.experiments.validation",
    "identification": "incipient_slip.experiments.identification",
}


def load(name: str) -> ModuleType:
    """Return the module of experiment `name` (a key of EXPERIMENTS)."""
    return importlib.import_module(EXPERIMENTS[name])
