"""The shipped Foxglove layout of a stabilization run, built with foxglove-sdk's layout model.

    python -m incipient_slip.nodes.viewer_layout [--s-d 0.3] [-o docs/viewers/stabilize.foxglove-layout.json]

Panels: ŝ against s_d (and the simulator's true stick ratio), F_N against its 6 kPa limit, y
against its 1.5 mm limit, the latest P_AC frame and its audio, the supervisor's verdict and the
run events. Limits and s_d are not on any topic, so a user script in the layout
(`/studio_script/limits`, derived from each GripCommand) draws them as lines; the numbers come
from `control` (one place). A test regenerates the file and checks every path against the
messages contract.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from incipient_slip.control import FAILURE_TRAVEL_MM, SAFETY_LIMIT_KPA

LAYOUT_PATH = Path(__file__).resolve().parents[3] / "docs" / "viewers" / "stabilize.foxglove-layout.json"
LIMITS_TOPIC = "/studio_script/limits"

_LIMITS_SCRIPT = """\
// Reference lines for the stabilization plots: s_d and the paper's failure limits, once per
// grip command (written by incipient_slip.nodes.viewer_layout; s_d is the launch's s_d).
import { Input } from "./types";

export const inputs = ["/grip/command"];
export const output = "%(topic)s";

type Limits = { s_d: number; safety_limit_kpa: number; failure_travel_mm: number };

export default function script(event: Input<"/grip/command">): Limits {
  return { s_d: %(s_d)r, safety_limit_kpa: %(force)r, failure_travel_mm: %(travel)r };
}
"""


def stabilize_layout(s_d: float = 0.3):
    """The layout (a `foxglove.layouts.Layout`) for a stabilization run with target `s_d`."""
    import foxglove.layouts as fl

    def plot(title_label: str, series, y_min=None, y_max=None):
        return fl.PlotPanel(title=title_label, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=value, label=label, **style) for value, label, style in series],
            y_axis_label=title_label, min_y_value=y_min, max_y_value=y_max, show_legend=True,
            is_synced=True, x_axis_val="timestamp", following_view_width=30.0))

    dashed = {"line_style": "dashed"}
    stick = plot("stick ratio", [("/slip/estimate.stick_ratio", "ŝ (estimate)", {}),
                                 ("/sim/truth.stick_ratio", "true (simulator)", {}),
                                 (f"{LIMITS_TOPIC}.s_d", "s_d", dashed)], 0.0, 1.0)
    force = plot("F_N kPa", [("/robot/state.normal_force_kpa", "F_N applied", {}),
                             ("/grip/command.normal_force_kpa", "F_N commanded", {}),
                             (f"{LIMITS_TOPIC}.safety_limit_kpa", "6 kPa limit", dashed)], 0.0)
    travel = plot("y mm", [("/object/pose.position_mm[1]", "y (object travel)", {}),
                           (f"{LIMITS_TOPIC}.failure_travel_mm", "1.5 mm limit", dashed)])
    pac = fl.PlotPanel(title="P_AC, latest frame", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value="/biotac/pac.pac_counts[:]", label="P_AC counts (22 samples)")],
        x_axis_val="index", y_axis_label="counts", show_legend=True))
    audio = fl.AudioPanel(title="P_AC audio", config=fl.AudioConfig(topic="/biotac/pac/audio"))
    verdict = fl.IndicatorPanel(title="verdict", config=fl.IndicatorConfig(
        path="/run/event.kind", style="background", fallback_label="running", fallback_color="#6b7280",
        rules=[fl.IndicatorRule(raw_value=kind, operator="=", color=color, label=kind)
               for kind, color in (("success", "#16a34a"), ("failure", "#dc2626"), ("fault", "#ea580c"))]))
    events = fl.RawMessagesPanel(title="run events", config=fl.RawMessagesConfig(topic_path="/run/event"))

    def column(*panels):
        return fl.SplitContainer(direction="column", items=[fl.SplitItem(content=p) for p in panels])

    return fl.Layout(
        content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=2, content=column(stick, force, travel)),
            fl.SplitItem(proportion=1, content=column(verdict, pac, audio, events))]),
        user_scripts={"limits": fl.UserScript(name="stabilization limits", source_code=_LIMITS_SCRIPT % {
            "topic": LIMITS_TOPIC, "s_d": float(s_d), "force": SAFETY_LIMIT_KPA,
            "travel": FAILURE_TRAVEL_MM})})


def layout_json(s_d: float = 0.3) -> str:
    """The layout file's text (indented, so that a change reads as a diff)."""
    return json.dumps(json.loads(stabilize_layout(s_d).to_json()), indent=1, ensure_ascii=False) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--s-d", type=float, default=0.3, help="target stick ratio drawn (default 0.3)")
    ap.add_argument("-o", "--out", type=Path, default=LAYOUT_PATH)
    args = ap.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(layout_json(args.s_d))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
