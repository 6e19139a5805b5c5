"""The transfer function as the page's editors see it.

A scalar scene's function (:class:`photon_fields.runtime.scene.transfer.TransferFunction`) is edited as control
points over the volume's histogram: the ``transfer`` message to and from the function, and the histogram drawn
behind the points. A label scene's (:class:`photon_fields.runtime.scene.labels.LabelTransfer`) is edited in the
label panel, :class:`LabelPanel`: one row per label present in the volume, each with a visibility, an albedo and
an opacity; the ``labels`` message changes some rows. :func:`edited_transfer` is the one entry the session calls
for either message, and refuses the message of the other kind, so a page can never turn a label scene into a
scalar one or the reverse.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.labels import LabelTransfer, labels_transfer, volume_labels
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.scene.volume import Volume
from photon_fields.runtime.viewer.messages import MAX_LABEL_EDITS, MessageError

#: Voxels above which the histogram is taken on every other voxel along each axis (repeatedly).
HISTOGRAM_VOXELS = 1 << 22
#: The most labels a label panel shows (one row each): ``pfn-view`` refuses a volume with more in one line.
MAX_PANEL_LABELS = 4096


def transfer_message(tf: TransferFunction) -> dict[str, Any]:
    """A transfer function as the page's editor reads it (the ``transfer`` message's fields, and its name)."""
    return {"points": [{"s": float(p), "opacity": float(o), "albedo": [float(a) for a in alb]}
                       for p, o, alb in zip(tf.points, tf.opacity, tf.albedo, strict=True)],
            "density_scale": float(tf.density_scale), "name": tf.name}


def edited_name(name: str) -> str:
    """The name of an edited function: the scene's, marked once as edited."""
    return name if name.endswith("(edited)") else f"{name} (edited)"


def transfer_from_message(fields: dict[str, Any], base: TransferFunction) -> TransferFunction:
    """The transfer function of a validated ``transfer`` message, named after the scene's ``base`` function.
    A :class:`MessageError` for one that leaves nothing visible (every opacity 0)."""
    points = fields["points"]
    if not any(p["opacity"] > 0 for p in points):
        raise MessageError("transfer: every opacity is 0: nothing would be visible")
    try:
        return TransferFunction(np.array([p["s"] for p in points]), np.array([p["albedo"] for p in points]),
                                np.array([p["opacity"] for p in points]), fields["density_scale"],
                                edited_name(base.name))
    except InputError as err:
        raise MessageError(f"transfer: {err}") from None


@dataclass(frozen=True, eq=False)
class LabelPanel:
    """The page's label panel: a row per label present in the volume, in increasing order (``values``, and
    ``counts`` its voxels), with the albedo, opacity and visibility the page set. Immutable: an edit is a new
    panel (the session's state is copied per frame).

    Visibility is kept apart from opacity so that a label shown again comes back at the opacity it had; the
    function rendered (:meth:`transfer`) gives a hidden label opacity 0. Hiding every label is allowed (the view
    is then empty): "hide all, then tick the one to see" is how a segmentation is explored."""

    values: np.ndarray  # (K,) int64, increasing
    counts: np.ndarray  # (K,) int64
    albedo: np.ndarray  # (K, 3) in [0, 1]
    opacity: np.ndarray  # (K,) in [0, 1], the slider's value (also while hidden)
    visible: np.ndarray  # (K,) bool
    density_scale: float
    name: str

    @classmethod
    def of(cls, tf: LabelTransfer, volume: Volume) -> LabelPanel:
        """The panel of the scene's function: a label it names with an opacity above 0 is visible at that
        opacity; one it names at opacity 0 (a hidden label of ``{"preset": "labels", "visible": [...]}``) or does
        not name (transparent) is hidden, at opacity 1 for when it is shown, with its own colour (the
        :func:`photon_fields.runtime.scene.labels.labels_transfer` palette where the function names none)."""
        grid = volume_labels(volume)
        colours = labels_transfer(volume, [], density_scale=tf.density_scale)
        albedo, opacity = colours.albedo.copy(), np.ones(grid.values.size)
        pos = np.searchsorted(grid.values, tf.labels)  # tf.labels are in the volume (the scene checked)
        albedo[pos] = tf.albedo
        opacity[pos] = np.where(tf.opacity > 0, tf.opacity, 1.0)
        visible = np.zeros(grid.values.size, dtype=bool)
        visible[pos] = tf.opacity > 0
        return cls(grid.values.copy(), grid.counts.copy(), albedo, opacity, visible, tf.density_scale, tf.name)

    def edited(self, edits: list[dict[str, Any]], density_scale: float | None = None) -> LabelPanel:
        """The panel after a validated ``labels`` message's edits (:func:`messages.label_edits`; none: []) and
        density scale (None: kept); a :class:`MessageError` naming the labels that are not in the volume (nothing
        is changed then)."""
        wanted = np.array([e["label"] for e in edits], dtype=np.int64)
        pos = np.minimum(np.searchsorted(self.values, wanted), self.values.size - 1)
        missing = wanted[self.values[pos] != wanted]
        if missing.size:
            listed = ", ".join(str(v) for v in missing[:8]) + (", ..." if missing.size > 8 else "")
            present = ", ".join(str(v) for v in self.values[:12]) + (", ..." if self.values.size > 12 else "")
            raise MessageError(f"labels: label{'s' if missing.size > 1 else ''} {listed} not in the volume "
                               f"(its labels: {present})")
        albedo, opacity, visible = self.albedo.copy(), self.opacity.copy(), self.visible.copy()
        for i, e in zip(pos, edits, strict=True):
            if "albedo" in e:
                albedo[i] = e["albedo"]
            if "opacity" in e:
                opacity[i] = e["opacity"]
            if "visible" in e:
                visible[i] = e["visible"]
        density = self.density_scale if density_scale is None else float(density_scale)
        return LabelPanel(self.values, self.counts, albedo, opacity, visible, density, self.name)

    def transfer(self) -> LabelTransfer:
        """The label transfer function the panel shows: every label present, a hidden one at opacity 0."""
        return LabelTransfer(self.values.copy(), self.albedo.copy(), np.where(self.visible, self.opacity, 0.0),
                             self.density_scale, edited_name(self.name))

    def message(self) -> dict[str, Any]:
        """The panel as the page builds it: a row per label (``label``, ``voxels``, ``albedo``, ``opacity``,
        ``visible``), the density scale, the function's name and how many labels one message may change."""
        rows = [{"label": int(v), "voxels": int(c), "albedo": [float(a) for a in alb], "opacity": float(o),
                 "visible": bool(vis)}
                for v, c, alb, o, vis in zip(self.values, self.counts, self.albedo, self.opacity, self.visible,
                                             strict=True)]
        return {"rows": rows, "density_scale": float(self.density_scale), "name": self.name,
                "max_edits": MAX_LABEL_EDITS}


def label_panel(tf: TransferFunction | LabelTransfer, volume: Volume) -> LabelPanel | None:
    """The label panel of a label scene's function, None for a scalar one (the control-point editor's)."""
    return LabelPanel.of(tf, volume) if isinstance(tf, LabelTransfer) else None


def edited_transfer(kind: str, fields: dict[str, Any], base: TransferFunction | LabelTransfer,
                    panel: LabelPanel | None) -> tuple[TransferFunction | LabelTransfer, LabelPanel | None]:
    """(the function to render, the label panel) after a validated ``transfer`` or ``labels`` message (``kind``)
    on a scene whose function is ``base`` and whose label panel is ``panel`` (None: a scalar scene). A
    :class:`MessageError` for the message of the other kind of scene, or an edit the function refuses."""
    if kind == "labels":
        if panel is None:
            raise MessageError("labels: this scene's transfer function is scalar (control points), not labels: "
                               "edit it with a 'transfer' message")
        panel = panel.edited(fields.get("labels", []), fields.get("density_scale"))
        return panel.transfer(), panel
    if panel is not None or not isinstance(base, TransferFunction):
        raise MessageError("transfer: this scene has a label transfer function, which has no control points: "
                           "edit it with a 'labels' message")
    return transfer_from_message(fields, base), None


def shows_something(tf: TransferFunction | LabelTransfer | None) -> bool:
    """Whether a function leaves anything visible (a label panel may hide every label; a field cannot be trained
    for an empty scene). None stands for the scene's own function, which does."""
    return tf is None or bool(np.any(tf.opacity > 0))


def volume_histogram(volume: Volume, bins: int = 64) -> list[float]:
    """log(1 + count) of the volume's normalized scalar per bin over [0, 1], scaled to a maximum of 1 (a volume
    of more than :data:`HISTOGRAM_VOXELS` voxels is subsampled)."""
    data = volume.data
    while data.size > HISTOGRAM_VOXELS:
        data = data[::2, ::2, ::2]
    counts, _ = np.histogram(data, bins=bins, range=(0.0, 1.0))
    h = np.log1p(counts.astype(np.float64))
    return [round(float(v), 4) for v in h / max(float(h.max()), 1e-12)]
