"""Helpers shared by the volume-reader tests (test_volume_io.py, test_vti.py, test_tiff.py)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.volume_io import load_volume


def expected_norm(raw: np.ndarray, window: tuple[float, float] | None = None) -> np.ndarray:
    """Independent reference for the normalization: (v - lo) / (hi - lo) clipped, as float32."""
    d = np.asarray(raw, dtype=np.float64)
    lo, hi = (float(d.min()), float(d.max())) if window is None else window
    return np.clip((d - lo) * (1.0 / (hi - lo)), 0.0, 1.0).astype(np.float32)


def one_line_error(path: Path, match: str, **kwargs: Any) -> str:
    """``load_volume(path, **kwargs)`` refused in one line that names the file and says ``match``."""
    with pytest.raises(InputError) as ei:
        load_volume(path, **kwargs)
    msg = str(ei.value)
    assert "\n" not in msg and path.name in msg, msg
    assert match.lower() in msg.lower(), msg
    return msg
