"""The transfer function as the page's editor sees it: the ``transfer`` message to and from a
:class:`photon_fields.runtime.scene.transfer.TransferFunction`, and the volume's histogram drawn behind the
control points."""

from __future__ import annotations

from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import Volume
from photon_fields.runtime.viewer.messages import MessageError

#: Voxels above which the histogram is taken on every other voxel along each axis (repeatedly).
HISTOGRAM_VOXELS = 1 << 22


def transfer_message(tf: TransferFunction) -> dict[str, Any]:
    """A transfer function as the page's editor reads it (the ``transfer`` message's fields, and its name)."""
    return {"points": [{"s": float(p), "opacity": float(o), "albedo": [float(a) for a in alb]}
                       for p, o, alb in zip(tf.points, tf.opacity, tf.albedo, strict=True)],
            "density_scale": float(tf.density_scale), "name": tf.name}


def transfer_from_message(fields: dict[str, Any], base: TransferFunction) -> TransferFunction:
    """The transfer function of a validated ``transfer`` message, named after the scene's ``base`` function.
    A :class:`MessageError` for one that leaves nothing visible (every opacity 0)."""
    points = fields["points"]
    if not any(p["opacity"] > 0 for p in points):
        raise MessageError("transfer: every opacity is 0: nothing would be visible")
    name = base.name if base.name.endswith("(edited)") else f"{base.name} (edited)"
    try:
        return TransferFunction(np.array([p["s"] for p in points]), np.array([p["albedo"] for p in points]),
                                np.array([p["opacity"] for p in points]), fields["density_scale"], name)
    except InputError as err:
        raise MessageError(f"transfer: {err}") from None


def volume_histogram(volume: Volume, bins: int = 64) -> list[float]:
    """log(1 + count) of the volume's normalized scalar per bin over [0, 1], scaled to a maximum of 1 (a volume
    of more than :data:`HISTOGRAM_VOXELS` voxels is subsampled)."""
    data = volume.data
    while data.size > HISTOGRAM_VOXELS:
        data = data[::2, ::2, ::2]
    counts, _ = np.histogram(data, bins=bins, range=(0.0, 1.0))
    h = np.log1p(counts.astype(np.float64))
    return [round(float(v), 4) for v in h / max(float(h.max()), 1e-12)]
