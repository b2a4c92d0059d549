"""matplotlib for the experiments' figures (no display needed, imported only when plotting) and
the names figures and tables give the methods."""
from __future__ import annotations

from pathlib import Path

from incipient_slip.paths import written_atomically

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
    """Write `fig` to `path` (creating its directory; .png added to a name without a suffix, as
    matplotlib would, so that the path returned is the file written), whole or not at all; close
    it and return the path."""
    path = Path(path)
    if not path.suffix:
        path = path.with_name(path.name + ".png")
    path.parent.mkdir(parents=True, exist_ok=True)
    if fig.get_layout_engine() is None:     # a figure made with layout="constrained" lays itself out
        fig.tight_layout()
    try:
        with written_atomically(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        pyplot().close(fig)
    return path
