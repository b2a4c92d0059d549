"""The optional extras (pyproject.toml) and the one line that names a missing one.

A lab PC that runs only the real devices installs `.[hardware]`: no simulator kernel (numba,
llvmlite), no figures (matplotlib), no parallel sweeps (dask). A command or node that needs one
of them says which extra brings it instead of a traceback: `slip ...` prints the line (exit 2);
a node module that imports the simulator raises `needed(exc)`, which the launcher reports as
its one line.
"""
from __future__ import annotations

__all__ = ["EXTRA_OF", "hint", "needed"]

# top-level module -> the extra that installs it
EXTRA_OF = {"numba": "sim", "llvmlite": "sim", "dask": "sim", "distributed": "sim",
            "matplotlib": "sim", "serial": "hardware", "sounddevice": "hardware",
            "rtde_control": "hardware", "rtde_receive": "hardware", "foxglove": "view"}


def hint(exc: ModuleNotFoundError) -> str | None:
    """The line naming the extra that brings the missing module, or None when it is none of ours."""
    top = (exc.name or "").split(".")[0]
    extra = EXTRA_OF.get(top)
    if extra is None:
        return None
    also = " (or [plots] for the figures alone)" if top == "matplotlib" else ""
    return f"this needs {top}, from the [{extra}] extra{also}: pip install -e '.[{extra}]'"


def needed(exc: ModuleNotFoundError) -> ModuleNotFoundError:
    """`exc` with the hint as its message (for `raise needed(exc) from None`), or `exc` itself."""
    line = hint(exc)
    return exc if line is None else ModuleNotFoundError(line, name=exc.name)
