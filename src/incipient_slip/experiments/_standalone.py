"""`slip reproduce calibration|validation` until the shared experiments runner is on this branch.

A minimal stand-in of the runner's Settings (budget, seed, work, docs, progress, options) and
of its docs-block writer, so the two modules run in the shape they will have there.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from incipient_slip.cli import fail
from incipient_slip.paths import repo_root

MODULES = {"calibration": "incipient_slip.experiments.calibration",
           "validation": "incipient_slip.experiments.validation"}


@dataclass
class Settings:
    """How to run one experiment (see the module docstring)."""

    budget: str = "quick"
    seed: int = 0
    work: Path = Path("runs/experiment")
    docs: Path | None = None
    progress: bool = True
    options: dict = field(default_factory=dict)
    jobs: int = 2

    @property
    def quick(self) -> bool:
        return self.budget == "quick"

    def pick(self, quick, full):
        """Return `quick` or `full` by the budget."""
        return quick if self.quick else full

    def option(self, name: str, default=None):
        """Return the option `name`, or `default` when it was not given."""
        value = self.options.get(name)
        return default if value is None else value

    @property
    def figures(self) -> Path:
        return (self.docs / "figures") if self.docs is not None else self.work / "figures"


def write_blocks(path: Path, blocks: dict) -> None:
    """Put each block between its `<!-- BEGIN name -->` / `<!-- END name -->` markers in the page."""
    text = path.read_text() if path.exists() else ""
    for name, body in blocks.items():
        begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
        if begin not in text:
            text += f"\n{begin}\n{end}\n"
        text = re.sub(re.escape(begin) + r".*?" + re.escape(end), lambda _: f"{begin}\n{body.strip()}\n{end}",
                      text, count=1, flags=re.S)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def _cmd(args) -> int:
    import importlib
    module = importlib.import_module(MODULES[args.experiment])
    quick = args.budget == "quick"
    work = Path(args.out or repo_root() / "runs" / (f"{args.experiment}-quick" if quick else args.experiment))
    docs = args.docs if args.docs is not None else (None if quick else repo_root() / "docs")
    skip = {"func", "command", "experiment", "budget", "seed", "out", "docs", "quiet"}
    settings = Settings(budget=args.budget, seed=args.seed, work=work, docs=docs, progress=not args.quiet,
                        options={k: v for k, v in vars(args).items() if k not in skip})
    try:
        results = module.run(settings)
    except ValueError as exc:
        return fail(str(exc), f"slip reproduce {args.experiment}")
    work.mkdir(parents=True, exist_ok=True)
    (work / "results.json").write_text(json.dumps(results, indent=1, default=str) + "\n")
    blocks = module.render(results)
    for body in blocks.values():
        print(body)
    page = (docs / module.DOC) if docs is not None else work / module.DOC
    write_blocks(page, blocks)
    print(f"wrote {page} and {work / 'results.json'} (simulated rig)")
    return 0


def register(subparsers, reproduce) -> None:
    """Add `slip reproduce calibration` and `slip reproduce validation`."""
    import importlib
    for name, mod in MODULES.items():
        module = importlib.import_module(mod)
        p = reproduce.add_parser(name, help=module.HELP, description=module.__doc__.split("\n\n")[0])
        g = p.add_mutually_exclusive_group()
        g.add_argument("--quick", dest="budget", action="store_const", const="quick", help="quick budget (minutes)")
        g.add_argument("--full", dest="budget", action="store_const", const="full", help="full budget (default)")
        p.set_defaults(budget="full", func=_cmd, experiment=name)
        p.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
        p.add_argument("--out", type=Path, help="work directory (default runs/NAME[-quick])")
        p.add_argument("--docs", type=Path, help="docs directory to write into (default docs/ on the full budget)")
        p.add_argument("--quiet", action="store_true", help="no progress output")
        module.add_arguments(p)
