"""What ``photon_fields.render`` returns: the rendered layers, savable as EXR + PNG and shown inline by notebooks.

Layers are linear radiance, ``(H, W, 3)`` float32, row 0 at the top: ``L`` (the image) = ``L_e`` (light seen
through the volume) + ``L_d`` (single scattering) + ``L_i`` (multiple scattering). The PNG and the notebook
view are tone-mapped by :func:`photon_fields.runtime.io.images.tonemap_srgb` (automatic exposure unless given).
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError

LAYERS = ("L", "L_d", "L_i", "L_e")


@dataclass(frozen=True, eq=False)
class Image:
    """A rendered image: ``layers`` (name -> (H, W, 3) float32) and ``info`` (how it was rendered, JSON-able)."""

    layers: dict[str, np.ndarray]
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def L(self) -> np.ndarray:  # noqa: N802  (the layer names)
        return self.layers["L"]

    @property
    def L_d(self) -> np.ndarray:  # noqa: N802  (the layer names)
        return self.layers["L_d"]

    @property
    def L_i(self) -> np.ndarray:  # noqa: N802  (the layer names)
        return self.layers["L_i"]

    @property
    def L_e(self) -> np.ndarray:  # noqa: N802  (the layer names)
        return self.layers["L_e"]

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width)."""
        return tuple(self.L.shape[:2])  # type: ignore[return-value]

    def to_srgb8(self, layer: str = "L", exposure: float | None = None) -> np.ndarray:
        """``layer`` tone-mapped to display sRGB, (H, W, 3) uint8."""
        from photon_fields.runtime.io.images import tonemap_srgb

        if layer not in self.layers:
            raise InputError("layer", f"unknown layer {layer!r} (available: {', '.join(self.layers)})")
        return tonemap_srgb(self.layers[layer], exposure)

    def save(self, path: str | Path, *, force: bool = False, exposure: float | None = None) -> list[Path]:
        """Write ``path`` (an ``.exr``: every layer, linear, with :attr:`info` in the header) and the PNG beside
        it (same stem), atomically; a ``.png`` path writes the same pair. An existing file is not replaced
        unless ``force``. Returns the paths written."""
        from photon_fields.runtime.io.images import write_image_set

        p = Path(path).expanduser()
        if p.suffix.lower() not in (".exr", ".png"):
            raise InputError(str(p), "must end in .exr or .png (both are written: the EXR and a PNG beside it)")
        exr = p.with_suffix(".exr")
        existing = [str(q) for q in (exr, exr.with_suffix(".png")) if q.exists() or q.is_symlink()]
        if existing and not force:
            raise InputError(existing[0], "exists; pass force=True to replace it")
        return write_image_set(exr, self.layers, {"photon_fields.render": json.dumps(self.info)}, exposure=exposure)

    def _repr_png_(self) -> bytes:
        """The tone-mapped image as PNG bytes (Jupyter shows it inline)."""
        from PIL import Image as PILImage

        buffer = io.BytesIO()
        PILImage.fromarray(self.to_srgb8()).save(buffer, format="PNG")
        return buffer.getvalue()

    def __repr__(self) -> str:
        h, w = self.shape
        return f"Image({w}x{h}, layers {', '.join(self.layers)}, method {self.info.get('method', '?')!r})"
