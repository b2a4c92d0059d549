"""The committed results are what the default command makes: the cheapest experiments rerun from
scratch (no cache, a fresh work directory, a copy of docs/) write the committed JSON and pages
again, all but their time lines."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import pytest

from incipient_slip.paths import docs_dir

TIME_KEY = re.compile(r"elapsed|wall|seconds|fit_s|train_s|delay_s|load_average|latency")
TIME_LINE = re.compile(r"Time to reproduce|took \*\*|wall on \d|in \d+(\.\d+)? s\b")


def _without_times(x):
    if isinstance(x, dict):
        return {k: _without_times(v) for k, v in x.items() if not TIME_KEY.search(k)}
    if isinstance(x, list):
        return [_without_times(v) for v in x]
    return x


def _page_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if not TIME_LINE.search(line)]


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("name, results, page", [
    ("calibration", "calibration_results.json", "calibration.md"),
    ("identification", "identification_results.json", "identification.md"),
])
def test_a_rerun_from_scratch_makes_the_committed_results(tmp_path, name, results, page):
    docs = tmp_path / "docs"
    shutil.copytree(docs_dir(), docs)
    run = subprocess.run([sys.executable, "-m", "incipient_slip.cli", "reproduce", name, "--quiet", "--no-cache",
                          "--docs", str(docs), "--out", str(tmp_path / "work")],
                         capture_output=True, text=True, timeout=880)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    committed = json.loads((docs_dir() / "figures" / results).read_text())
    again = json.loads((docs / "figures" / results).read_text())
    assert _without_times(again) == _without_times(committed)
    assert _page_lines((docs / page).read_text()) == _page_lines((docs_dir() / page).read_text())
