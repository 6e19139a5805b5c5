"""Label volumes: a categorical transfer function, classified per voxel, and a helper that builds one.

A segmentation stores one integer label per voxel (0 = background, 3 = liver, 7 = a vessel, ...). Classifying
it like a scalar field is wrong: trilinear interpolation *before* classification makes the border between
label 3 and label 7 pass through 4, 5 and 6, so a continuous transfer function shows colours that no label
has. Here the label identity stays exact end to end:

- :func:`volume_labels` recovers each voxel's raw integer label from the normalized grid and the window it
  was normalized with (:class:`photon_fields.runtime.scene.volume.Volume` records both), and maps the K distinct
  labels present to dense indices 0..K-1 (a float32 grid of exact small integers). No second copy of the raw
  data is kept; the result is cached on the volume. A volume whose values are not integers, or whose window
  clipped them, is refused in one line.
- :class:`LabelTransfer` maps labels to (albedo, opacity); :meth:`LabelTransfer.tables` builds per-index
  tables of K entries (labels the function does not name are transparent). The medium
  (:func:`photon_fields.runtime.transport.medium.build_medium`) then looks the nearest voxel's index up
  without any interpolation, so every albedo and extinction a renderer sees is one label's own.

Nearest-neighbour classification rather than per-label interpolation of the indicator functions (an argmax of
the trilinear weights per label, which gives smoother borders): both never invent a colour, nearest costs one
voxel read where the argmax needs all eight corners and a small vote, and nearest is what segmentation
viewers show, voxel for voxel. The smoother borders are left as a possible refinement; the majorant grid
built here (over the trilinear support) bounds both.

JSON form (a TF file or a scene's ``transfer_function``; unknown keys are refused)::

    {"labels": {"3": {"albedo": [0.9, 0.2, 0.2], "opacity": 1.0},
                "7": {"albedo": [0.2, 0.5, 0.9], "opacity": 0.5}},
     "density_scale": 100, "name": "organs"}

or ``{"preset": "labels"}`` (optionally with ``"visible": [3, 7]`` and ``"density_scale"``), resolved against
the volume by :func:`labels_transfer`. ``density_scale`` is the extinction of opacity 1 per longest box side,
as for the points form; its default here is :data:`DEFAULT_LABEL_DENSITY`, because segmented structures are
solid objects.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

import numpy as np

from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.scene.volume import Volume

#: Extinction of opacity 1 per longest box side when a label function does not say (solid-looking objects).
DEFAULT_LABEL_DENSITY = 100.0
#: Widest raw label range accepted: beyond it float32 normalized values no longer separate neighbouring labels
#: with a safe margin (their spacing 1 / range approaches float32's resolution).
MAX_LABEL_SPAN = 1 << 20
_LABELS_KEYS = ("labels", "density_scale", "name")
_LABEL_KEYS = ("albedo", "opacity")
_INTEGER = re.compile(r"[+-]?\d+")

#: Well-separated albedos for the helper, in order: saturated hues first, then darker and lighter variants.
#: Albedos stay at or above ~0.1 per channel so that no label turns into a black absorber.
PALETTE: tuple[tuple[float, float, float], ...] = (
    (0.90, 0.15, 0.15), (0.15, 0.50, 0.90), (0.20, 0.75, 0.25), (0.95, 0.80, 0.15), (0.60, 0.30, 0.80),
    (0.95, 0.50, 0.10), (0.15, 0.80, 0.80), (0.90, 0.45, 0.70), (0.60, 0.85, 0.15), (0.55, 0.35, 0.20),
    (0.20, 0.25, 0.60), (0.85, 0.85, 0.85), (0.60, 0.10, 0.25), (0.10, 0.50, 0.45), (0.95, 0.85, 0.60),
    (0.45, 0.45, 0.45), (0.75, 0.65, 0.95), (0.45, 0.60, 0.10), (0.95, 0.60, 0.45), (0.35, 0.90, 0.60),
)  # fmt: skip


class LabelGrid(NamedTuple):
    """The labels of a volume: ``values`` (K,) int64 the distinct raw labels present, increasing; ``counts``
    (K,) their voxel counts; ``index`` float32 (nx, ny, nz) each voxel's dense index into ``values``."""

    values: np.ndarray
    counts: np.ndarray
    index: np.ndarray


def volume_labels(volume: Volume, what: str = "volume") -> LabelGrid:
    """The volume's integer labels (module docstring), computed once per volume, chunk by chunk.

    Raises a one-line :class:`InputError` naming ``what`` when the raw values are unknown, were clipped by
    the window, span more than :data:`MAX_LABEL_SPAN`, or are not integers."""
    if volume._labels:
        return volume._labels[0]
    win, rng = volume.window, volume.value_range
    if win is None or rng is None:
        raise InputError(what, "records no raw values (build it with make_volume or a reader): a label transfer "
                               "function needs the raw integer labels")
    lo, hi = win
    if rng[0] < lo or rng[1] > hi:
        raise InputError(what, f"its window [{lo:g}, {hi:g}] clips the raw values (range [{rng[0]:g}, {rng[1]:g}]), "
                               "which loses label identity: load a label volume without a window")
    if rng[1] - rng[0] > MAX_LABEL_SPAN:
        raise InputError(what, f"label values span [{rng[0]:g}, {rng[1]:g}], wider than {MAX_LABEL_SPAN} "
                               "(relabel it to consecutive integers first)")
    span = hi - lo
    tol = 1e-3 + span * 2.0**-23  # float32 normalization error is at most span * 2^-24
    base = int(round(rng[0]))
    n = int(round(rng[1])) - base + 1
    data = volume.data
    step = max(1, (1 << 22) // max(1, data.shape[1] * data.shape[2]))

    def offsets(s: int) -> np.ndarray:
        raw = lo + data[s : s + step].astype(np.float64) * span
        r = np.rint(raw)
        bad = np.abs(raw - r) > tol
        if bad.any():
            at = np.argwhere(bad)[0]
            index = (int(at[0]) + s, int(at[1]), int(at[2]))
            raise InputError(what, f"is not a label volume: voxel {index} has the value {raw[tuple(at)]:.6g}, not "
                                   "an integer (a label transfer function needs integer labels)")
        return (r - base).astype(np.int64)

    counts = np.zeros(n, dtype=np.int64)
    for s in range(0, data.shape[0], step):
        counts += np.bincount(offsets(s).ravel(), minlength=n)
    present = np.flatnonzero(counts)
    dense = np.full(n, -1, dtype=np.int64)
    dense[present] = np.arange(present.size)
    index = np.empty(data.shape, dtype=np.float32)
    for s in range(0, data.shape[0], step):
        index[s : s + step] = dense[offsets(s)]
    grid = LabelGrid(present + base, counts[present], index)
    volume._labels.append(grid)
    return grid


def _labels_of(volume: Volume, what: str) -> LabelGrid:
    """:func:`volume_labels`, its refusals naming ``what`` (a TF file or scene entry) and then the volume."""
    try:
        return volume_labels(volume, what)
    except InputError as err:
        raise InputError(what, f"volume '{volume.name}' {err.problem}") from None


def _label_list(values: Any, limit: int = 12) -> str:
    items = [str(int(v)) for v in values]
    return ", ".join(items[:limit]) + (f", ... ({len(items)} in all)" if len(items) > limit else "")


@dataclass(frozen=True, eq=False)
class LabelTransfer:
    """A categorical transfer function: raw integer label -> (albedo RGB, opacity); labels it does not name
    are transparent. ``sigma_t = opacity * density_scale``, as for the points form."""

    labels: np.ndarray  # (K,) int64, strictly increasing
    albedo: np.ndarray  # (K, 3) in [0, 1]
    opacity: np.ndarray  # (K,) in [0, 1]
    density_scale: float = DEFAULT_LABEL_DENSITY
    name: str = "labels"
    #: Tells the medium to classify per voxel (nearest) and index its tables exactly.
    categorical: ClassVar[bool] = True

    def __post_init__(self) -> None:
        what = f"label transfer function '{self.name}'"
        lab = np.asarray(self.labels)
        alb = np.asarray(self.albedo, dtype=np.float64)
        opa = np.asarray(self.opacity, dtype=np.float64)
        if lab.ndim != 1 or lab.size == 0:
            raise InputError(what, "needs at least one label")
        if not np.issubdtype(lab.dtype, np.integer):
            raise InputError(what, f"labels must be integers, got dtype {lab.dtype}")
        lab = lab.astype(np.int64)
        if alb.shape != (lab.size, 3):
            raise InputError(what, f"albedo must have shape ({lab.size}, 3), got {alb.shape}")
        if opa.shape != (lab.size,):
            raise InputError(what, f"opacity must have shape ({lab.size},), got {opa.shape}")
        if np.any(np.diff(lab) <= 0):
            raise InputError(what, f"labels must be distinct and increasing, got {_label_list(lab)}")
        for arr, name in ((alb, "albedo"), (opa, "opacity")):
            if not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr > 1):
                raise InputError(what, f"{name} values must be finite and lie in [0, 1]")
        ds = float(self.density_scale)
        if not np.isfinite(ds) or ds <= 0:
            raise InputError(what, f"density_scale must be a positive number, got {self.density_scale}")
        object.__setattr__(self, "labels", lab)
        object.__setattr__(self, "albedo", alb)
        object.__setattr__(self, "opacity", opa)
        object.__setattr__(self, "density_scale", ds)

    # -- binding to a volume ------------------------------------------------------------------------
    def check(self, volume: Volume, what: str = "transfer function") -> LabelGrid:
        """The volume's labels, after refusing (one line naming ``what``) a volume that is not a label volume
        or labels of this function that the volume does not contain (a typo, or the wrong volume)."""
        grid = _labels_of(volume, what)
        missing = np.setdiff1d(self.labels, grid.values)
        if missing.size:
            raise InputError(what, f"label{'s' if missing.size > 1 else ''} {_label_list(missing)} not in volume "
                                   f"'{volume.name}' (its labels: {_label_list(grid.values)})")
        return grid

    def tables(self, volume: Volume, what: str = "transfer function") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(index grid float32 (nx, ny, nz), extinction (K,), albedo (K, 3)) over the K labels present in
        ``volume``: entry k belongs to the k-th label present; labels this function does not name get
        extinction 0 (and albedo 0, never read: nothing collides there)."""
        grid = self.check(volume, what)
        pos = np.searchsorted(self.labels, grid.values)
        named = pos < self.labels.size
        named[named] = self.labels[pos[named]] == grid.values[named]
        ext = np.zeros(grid.values.size)
        alb = np.zeros((grid.values.size, 3))
        ext[named] = self.opacity[pos[named]] * self.density_scale
        alb[named] = self.albedo[pos[named]]
        return grid.index, ext, alb

    # -- JSON ----------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "density_scale": self.density_scale,
                "labels": {str(int(lab)): {"albedo": [float(a) for a in alb], "opacity": float(o)}
                           for lab, alb, o in zip(self.labels, self.albedo, self.opacity, strict=True)}}

    @classmethod
    def from_dict(cls, d: Any, what: str = "transfer function", volume: Volume | None = None) -> LabelTransfer:
        """The ``{"labels": {...}}`` form (module docstring); with ``volume``, also checked against it."""
        if not isinstance(d, dict):
            raise InputError(what, "must be a JSON object")
        check_keys(d, _LABELS_KEYS, what)
        entries = d.get("labels")
        if not isinstance(entries, dict) or not entries:
            raise InputError(what, "'labels' must be a non-empty object {\"<label>\": {\"albedo\": [r, g, b], "
                                   "\"opacity\": o}, ...}")
        rows: dict[int, tuple[list[float], float]] = {}
        for key, entry in entries.items():
            where = f"{what} labels[{key!r}]"
            if not _INTEGER.fullmatch(str(key).strip()):
                raise InputError(where, f"a label must be an integer, got {key!r}")
            label = int(str(key).strip())
            if label in rows:
                raise InputError(where, f"label {label} is given twice")
            if not isinstance(entry, dict):
                raise InputError(where, f"must be an object {{\"albedo\": [r, g, b], \"opacity\": o}}, got {entry!r}")
            check_keys(entry, _LABEL_KEYS, where, required=_LABEL_KEYS)
            try:
                alb = [float(v) for v in entry["albedo"]]
                opa = float(entry["opacity"])
            except (TypeError, ValueError):
                raise InputError(where, "needs numeric 'albedo' [r, g, b] and 'opacity', got "
                                        f"{json.dumps(entry)[:80]}") from None
            if len(alb) != 3:
                raise InputError(where, f"albedo must have three components [r, g, b], got {entry['albedo']!r}")
            rows[label] = (alb, opa)
        ds = d.get("density_scale", DEFAULT_LABEL_DENSITY)
        if isinstance(ds, bool) or not isinstance(ds, (int, float)):
            raise InputError(what, f"'density_scale' must be a number, got {ds!r}")
        order = sorted(rows)
        try:
            tf = cls(np.array(order, dtype=np.int64), np.array([rows[k][0] for k in order]),
                     np.array([rows[k][1] for k in order]), float(ds), str(d.get("name", "labels")))
        except InputError as err:
            raise InputError(what, err.problem) from None
        if volume is not None:
            tf.check(volume, what)
        return tf

    def save(self, path: str | Path, *, force: bool = False) -> None:
        """Write :meth:`to_dict` as a TF file a scene can name, atomically; an existing file is replaced only
        with ``force`` (as :meth:`TransferFunction.save`)."""
        from photon_fields.runtime.io.atomic import atomic_path

        if Path(path).exists() and not force:
            raise InputError(str(path), "exists; pass force=True to replace it")
        with atomic_path(path) as tmp:
            Path(tmp).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path, volume: Volume | None = None) -> LabelTransfer:
        """A TF file in the labels form (any other form is refused, naming the file)."""
        from photon_fields.runtime.scene.transfer import TransferFunction

        tf = TransferFunction.load(path, volume=volume)
        if not isinstance(tf, LabelTransfer):
            raise InputError(str(path), "is not a label transfer function (it has no 'labels' entry)")
        return tf


def palette(n: int) -> np.ndarray:
    """``n`` distinct albedos: :data:`PALETTE`, then golden-angle hues at alternating lightness."""
    out = [PALETTE[i] for i in range(min(n, len(PALETTE)))]
    for i in range(len(PALETTE), n):
        hue = (i * 0.618033988749895) % 1.0
        light = (0.85, 0.6, 0.4)[i % 3]
        rgb = np.clip(np.abs(np.mod(hue * 6.0 + np.array([0.0, 4.0, 2.0]), 6.0) - 3.0) - 1.0, 0.0, 1.0)
        out.append(tuple(0.1 + (light - 0.1) * (0.35 + 0.65 * rgb)))
    return np.array(out, dtype=np.float64).reshape(n, 3)


def labels_transfer(volume: Volume, visible: Any = None, *, background: int | None = 0,
                    density_scale: float = DEFAULT_LABEL_DENSITY, name: str = "labels",
                    what: str = "transfer function") -> LabelTransfer:
    """A label transfer function for the labels present in ``volume``, each with its own colour.

    Every label present gets an entry (so a saved file lists them all, ready to edit); colours follow
    :func:`palette` in increasing label order, skipping ``background``, so no two labels share one.
    ``visible``: None shows every label but ``background`` (opacity 1; background 0, None for no background);
    a list shows exactly those labels (each must be present), every other label gets opacity 0."""
    grid = _labels_of(volume, what)
    values = grid.values
    if visible is None:
        shown = values != background if background is not None else np.ones(values.size, dtype=bool)
    else:
        if isinstance(visible, (str, bytes)) or not isinstance(visible, (list, tuple, np.ndarray)):
            raise InputError(f"{what} visible", f"must be a list of labels, got {visible!r}")
        wanted = []
        for v in visible:
            integral = isinstance(v, (int, np.integer)) or (isinstance(v, float) and v.is_integer())
            if isinstance(v, bool) or not integral:
                raise InputError(f"{what} visible", f"labels must be integers, got {v!r}")
            wanted.append(int(v))
        missing = sorted(set(wanted) - {int(v) for v in values})
        if missing:
            raise InputError(f"{what} visible", f"label{'s' if len(missing) > 1 else ''} {_label_list(missing)} "
                                                f"not in volume '{volume.name}' (its labels: {_label_list(values)})")
        shown = np.isin(values, wanted)
    coloured = values != background if background is not None else np.ones(values.size, dtype=bool)
    albedo = np.full((values.size, 3), 0.8)
    albedo[coloured] = palette(int(coloured.sum()))
    try:
        return LabelTransfer(values.copy(), albedo, shown.astype(np.float64), density_scale, name)
    except InputError as err:
        raise InputError(what, err.problem) from None


__all__ = ["DEFAULT_LABEL_DENSITY", "LabelGrid", "LabelTransfer", "PALETTE", "labels_transfer", "palette",
           "volume_labels"]
