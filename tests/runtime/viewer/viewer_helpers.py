"""Small inputs for the viewer tests: a 32^3 scene at a tiny frame size and an analytic stand-in for a photon
field's estimator (no torch, no training: the session logic is what these tests check)."""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
from conftest import tiny_scene_dict

from photon_fields.runtime.scene.scene import Scene, scene_from_dict
from photon_fields.runtime.viewer.launch import ViewerInputs
from photon_fields.runtime.viewer.messages import Message, validate
from photon_fields.runtime.viewer.session import ViewerSession

SIZE = 24


def tiny_scene(size: int = SIZE) -> Scene:
    return scene_from_dict(tiny_scene_dict("blobs")).with_overrides(width=size, height=size)


class AnalyticField:
    """Q(x, d, g) = (0.2 + 0.3 (1 + x_y)) (1 + 0.8 g d_x) per channel (tinted): smooth, positive, and different
    for every g, so a frame at another g must differ."""

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        base = (0.2 + 0.3 * (1.0 + x[1])) * (1.0 + 0.8 * g * d[0])
        return (np.stack([base, 0.8 * base, 0.6 * base]) * 0.5).astype(np.float32)


def msg(kind: str, **fields: Any) -> Message:
    return validate({"type": kind, **fields})


def make_session(out_dir: Path, renderer: str = "neural", size: int = SIZE, **kw: Any) -> ViewerSession:
    return ViewerSession(tiny_scene(size), estimator=AnalyticField(), out_dir=out_dir, seed=5, width=size,
                         height=size, renderer=renderer, **kw)


def inputs(out_dir: Path, size: int = SIZE, renderer: str | None = "pt") -> ViewerInputs:
    sc = tiny_scene(size)
    return ViewerInputs(sc, AnalyticField(), None, out_dir, 5, size, size, renderer, {"bundle": None, "map": None})


def split_frame(data: bytes) -> tuple[dict[str, Any], bytes]:
    """A binary frame message -> (header, image bytes)."""
    n = struct.unpack(">I", data[:4])[0]
    return json.loads(data[4:4 + n]), data[4 + n:]
