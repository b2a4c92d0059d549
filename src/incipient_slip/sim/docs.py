"""Write the generated calibration block into docs/simulator.md (between markers)."""
from __future__ import annotations

from pathlib import Path

BEGIN, END = "<!-- calibration:begin (written by slip sim calibrate) -->", "<!-- calibration:end -->"


def write_simulator_doc(path: Path, table: str, figures: list[str]) -> None:
    """Replace the calibration block of `path` (create the file if missing) with `table` and figures."""
    figs = "\n".join(f"![simulated rig: {f}](figures/{f})\n*Simulated rig, not a measurement: `{f}`.*\n"
                     for f in figures)
    block = f"{BEGIN}\n{table}\n\n{figs}{END}"
    path = Path(path)
    text = path.read_text() if path.exists() else "# Simulator\n\n## Calibration\n\n" + BEGIN + "\n" + END + "\n"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        text = head + block + tail
    else:
        text = text.rstrip() + "\n\n## Calibration\n\n" + block + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
