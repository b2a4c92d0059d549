"""BioTac ADC: scaling, quantization and clipping."""
from __future__ import annotations

import numpy as np


def pac_to_counts(pac_pa: np.ndarray, pa_per_count: float, range_pa: float) -> np.ndarray:
    """Return int16 P_AC counts: round(P / pa_per_count), clipped at +/- range_pa."""
    lim = np.floor(range_pa / pa_per_count)
    x = np.rint(pac_pa * (1.0 / pa_per_count))
    np.minimum(x, lim, out=x)
    np.maximum(x, -lim, out=x)
    return x.astype(np.int16)


def to_uint12(x: np.ndarray, full_scale: int = 4095) -> np.ndarray:
    """Return uint16 counts rounded and clipped to [0, full_scale]."""
    x = np.rint(x)
    np.minimum(x, full_scale, out=x)
    np.maximum(x, 0, out=x)
    return x.astype(np.uint16)
