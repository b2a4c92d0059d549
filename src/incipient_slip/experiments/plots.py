"""matplotlib for the experiments' figures (no display needed, imported only when plotting) and
the names figures and tables give the methods."""
from __future__ import annotations

from pathlib import Path

SIM_LABEL = "simulated rig"     # in every figure title: these are statements about the simulator
# how tables and figures name the methods (messages.METHODS)
METHOD_LABELS = {"none": "no action", "vibrotactile": "vibrotactile", "e1": "E1", "e4": "E4",
                 "e10": "E10", "e19": "E19", "injection": "injection (ours)"}


def pyplot():
    """Return matplotlib.pyplot on the non-interactive Agg backend."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def save(fig, path: Path, dpi: int = 110) -> Path:
    """Write `fig` to `path` (creating its directory), close it and return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if fig.get_layout_engine() is None:     # a figure made with layout="constrained" lays itself out
        fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path
