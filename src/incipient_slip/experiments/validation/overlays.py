"""An identified rig's params overlays (`--params`): one overlay from a session per material, and
the points its Table is predicted at (the values, then each interval's ends)."""
from __future__ import annotations


def merge_overlays(docs: list[dict]) -> dict:
    """Return one overlay from several sessions of one rig (one per material): the materials of
    all, the pad's and the rig's entries from the last; provenance lists every session."""
    merged: dict = {"provenance": {}}
    for doc in docs:
        for section, entries in doc.items():
            if section == "provenance":
                continue
            if section == "materials":
                merged.setdefault("materials", {}).update(entries)
            else:
                merged.setdefault(section, {}).update(entries)
    sessions = [d["provenance"] for d in docs]
    last = sessions[-1]
    merged["provenance"] = {**last, "material": ", ".join(str(p.get("material")) for p in sessions),
                            "date": ", ".join(sorted({str(p.get("date")) for p in sessions})),
                            "sessions": sessions}
    return merged


def overlay_points(doc: dict) -> dict[str, dict]:
    """Return {point name: params} of an identified rig: the overlay's values, then each entry
    with an interval at its low and high end (one at a time). An end at the value itself (an
    entry without an interval, or one-sided) would repeat the identified point's Table: left out."""
    from incipient_slip.sim.scene import apply_overlay, load_params, overlay_entries

    base, _, _ = load_params("default")
    points = {"identified": apply_overlay(base, doc)}
    for name, entry in overlay_entries(doc).items():
        for end, v in zip(("low", "high"), entry.get("interval") or ()):
            if v == entry.get("value"):
                continue
            points[f"{'.'.join(name[-2:])} {end} {v:.3g}"] = apply_overlay(base, doc, values={name: v})
    return points
