"""Every experiment has the one shape, and its rendered blocks have a home in its docs page."""
import json
import re
import sys
from pathlib import Path

import pytest

from incipient_slip.experiments import EXPERIMENTS, load
from incipient_slip.experiments.cli import render_blocks
from incipient_slip.experiments.docs import markers, replace_blocks
from incipient_slip.paths import repo_root

sys.path.insert(0, str(Path(__file__).parent))
from samples import SAMPLES, docs_page  # noqa: E402

MARKER = re.compile(r"<!-- BEGIN ([\w-]+) -->")


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_experiment_has_the_shape(name):
    module = load(name)
    assert module.NAME == name and module.HELP and module.__doc__
    assert all(callable(getattr(module, f)) for f in ("add_arguments", "run", "render"))
    assert docs_page(name).is_file()


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_render_gives_blocks_whose_markers_are_in_the_docs_page(name):
    results = json.loads(json.dumps(SAMPLES[name](), allow_nan=True))     # as --render-only reads them
    blocks = render_blocks(name, results)
    assert f"{name}-time" in blocks and blocks and all(isinstance(b, str) and b.strip() for b in blocks.values())
    page = docs_page(name).read_text()
    for block in blocks:
        begin, end = markers(block)
        assert page.count(begin) == 1 and page.count(end) == 1, f"{docs_page(name)} lacks block {block}"


def test_every_marker_in_the_docs_belongs_to_an_experiment():
    rendered = {b for name in EXPERIMENTS for b in render_blocks(
        name, json.loads(json.dumps(SAMPLES[name](), allow_nan=True)))}
    found = {m for page in (repo_root() / "docs").glob("*.md") for m in MARKER.findall(page.read_text())}
    assert found <= rendered, f"markers no experiment writes: {sorted(found - rendered)}"


def test_the_stabilization_page_shows_its_committed_results():
    """docs/stabilization.md is what `slip reproduce stabilization --render-only` writes."""
    page = (repo_root() / "docs" / "stabilization.md").read_text()
    blocks = load("stabilization").render(SAMPLES["stabilization"]())
    assert replace_blocks(page, blocks) == page
