"""Transfer functions: normalized scalar -> RGB albedo and extinction.

Parameters
----------
points : (n,) float, strictly increasing, inside [0, 1]
    Control-point positions on the normalized scalar axis.
albedo : (n, 3) float in [0, 1]
    Single-scattering albedo (RGB) at each control point.
opacity : (n,) float in [0, 1]
    Relative density at each control point.
density_scale : float > 0
    Extinction coefficient for opacity 1, per unit of world length. The world box's longest side is 1
    (see :mod:`photon_fields.runtime.scene.volume`), so ``density_scale = 50`` means an opacity-1 region attenuates by
    ``exp(-50)`` across the whole box.

The mapping is piecewise linear between control points and constant beyond the first/last point:
``sigma_t(s) = opacity(s) * density_scale`` and ``albedo(s)``. Renderers use a lookup table of
``LUT_SIZE`` entries (:meth:`TransferFunction.lut`); the table is linearly interpolated, so the maximum
of the table over an index range bounds the extinction over the corresponding scalar range, which is
what the majorant grid relies on (:mod:`photon_fields.runtime.transport.medium`).

Label (segmentation) volumes use the categorical form instead, ``{"labels": {"3": {"albedo", "opacity"}}}``
or ``{"preset": "labels"}``: :meth:`TransferFunction.from_dict` and :meth:`TransferFunction.load` return a
:class:`photon_fields.runtime.scene.labels.LabelTransfer` for them (see that module for why labels are never
interpolated).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from photon_fields.runtime.errors import InputError, check_keys

if TYPE_CHECKING:
    from photon_fields.runtime.scene.volume import Volume

LUT_SIZE = 1024
#: The preset name resolved from the volume's histogram (:mod:`photon_fields.runtime.scene.auto_transfer`).
AUTO = "auto"
#: The preset name built from the labels present in a label volume
#: (:func:`photon_fields.runtime.scene.labels.labels_transfer`).
LABELS = "labels"
#: Keys of the preset and points forms of a transfer function and of one control point (anything else is refused;
#: the labels form checks its own keys, photon_fields.runtime.scene.labels).
_PRESET_KEYS = ("preset", "density_scale")
_LABELS_PRESET_KEYS = ("preset", "density_scale", "visible")
_POINTS_KEYS = ("points", "density_scale", "name")
_POINT_KEYS = ("s", "albedo", "opacity")


@dataclass(frozen=True, eq=False)
class TransferFunction:
    points: np.ndarray
    albedo: np.ndarray
    opacity: np.ndarray
    density_scale: float = 50.0
    name: str = "custom"

    def __post_init__(self) -> None:
        what = f"transfer function '{self.name}'"
        pts = np.asarray(self.points, dtype=np.float64)
        alb = np.asarray(self.albedo, dtype=np.float64)
        opa = np.asarray(self.opacity, dtype=np.float64)
        if pts.ndim != 1 or pts.size == 0:
            raise InputError(what, "needs at least one control point")
        if alb.shape != (pts.size, 3):
            raise InputError(what, f"albedo must have shape ({pts.size}, 3), got {alb.shape}")
        if opa.shape != (pts.size,):
            raise InputError(what, f"opacity must have shape ({pts.size},), got {opa.shape}")
        for arr, label in ((pts, "points"), (alb, "albedo"), (opa, "opacity")):
            if not np.all(np.isfinite(arr)):
                raise InputError(what, f"{label} contain non-finite values")
        if np.any(np.diff(pts) <= 0):
            raise InputError(what, f"control points must be strictly increasing, got {pts.tolist()}")
        if pts[0] < 0 or pts[-1] > 1:
            raise InputError(what, "control points must lie in [0, 1]")
        if np.any(alb < 0) or np.any(alb > 1):
            raise InputError(what, "albedo values must lie in [0, 1]")
        if np.any(opa < 0) or np.any(opa > 1):
            raise InputError(what, "opacity values must lie in [0, 1]")
        ds = float(self.density_scale)
        if not np.isfinite(ds) or ds <= 0:
            raise InputError(what, f"density_scale must be a positive number, got {self.density_scale}")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "albedo", alb)
        object.__setattr__(self, "opacity", opa)
        object.__setattr__(self, "density_scale", ds)

    # -- evaluation ---------------------------------------------------------------------------------
    def evaluate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact piecewise-linear evaluation: returns (albedo (..., 3), extinction (...))."""
        s = np.asarray(s, dtype=np.float64)
        alb = np.stack([np.interp(s, self.points, self.albedo[:, c]) for c in range(3)], axis=-1)
        ext = np.interp(s, self.points, self.opacity) * self.density_scale
        return alb, ext

    def lut(self, size: int = LUT_SIZE) -> tuple[np.ndarray, np.ndarray]:
        """Tables sampled at ``s = i / (size - 1)``: (albedo (size, 3) float64, extinction (size,) float64)."""
        return self.evaluate(np.linspace(0.0, 1.0, size))

    # -- JSON ----------------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "density_scale": self.density_scale,
            "points": [
                {"s": float(s), "albedo": [float(a) for a in alb], "opacity": float(o)}
                for s, alb, o in zip(self.points, self.albedo, self.opacity, strict=True)
            ],
        }

    @classmethod
    def from_dict(cls, d: Any, what: str = "transfer function", volume: Volume | None = None) -> Any:
        """A transfer function from its JSON form: ``{"preset": NAME}`` (optionally with ``density_scale``)
        or ``{"points": [{"s", "albedo", "opacity"}, ...], "density_scale": ..., "name": ...}``, or, for a
        label volume, a :class:`photon_fields.runtime.scene.labels.LabelTransfer` from ``{"labels": {...}}`` or
        ``{"preset": "labels", "visible": [...]}`` (resolved against ``volume``). Unknown
        keys are refused, at the top level and in every point (``what points[2]``), so that a typo such as
        ``"densty_scale"`` cannot silently render with the default.

        ``{"preset": "auto"}`` is keyed to ``volume``'s histogram
        (:mod:`photon_fields.runtime.scene.auto_transfer`) and is resolved here, to concrete points: without a
        volume it is refused. The points form is also what the viewer's editor sends (its ``transfer``
        message, :func:`photon_fields.runtime.viewer.transfer_edit.transfer_message`), so an edited function
        saved with :meth:`save` is a file a scene can name."""
        if not isinstance(d, dict):
            raise InputError(what, "must be a JSON object")
        given = [k for k in ("preset", "points", "labels") if k in d]
        if len(given) > 1:
            raise InputError(what, f"give one of 'preset', 'points' or 'labels', not {' and '.join(map(repr, given))}")
        if "labels" in d:
            from photon_fields.runtime.scene.labels import LabelTransfer

            return LabelTransfer.from_dict(d, what, volume)
        if d.get("preset") == LABELS:
            return _labels_preset(d, what, volume)
        if "preset" in d:
            check_keys(d, _PRESET_KEYS, what)
            if d["preset"] == AUTO:
                return _auto(d, what, volume)
            tf = preset(str(d["preset"]), what=what)
            if "density_scale" in d:
                ds = _number(d, "density_scale", what)
                tf = _relabelled(what, lambda: TransferFunction(tf.points, tf.albedo, tf.opacity, ds, tf.name))
            return tf
        check_keys(d, _POINTS_KEYS, what)
        pts = d.get("points")
        if not isinstance(pts, list) or not pts:
            raise InputError(what, "needs 'preset' (a preset name) or 'points' (a non-empty list of "
                                   "{s, albedo, opacity} objects)")
        s, alb, opa = [], [], []
        for i, p in enumerate(pts):
            where = f"{what} points[{i}]"
            if not isinstance(p, dict):
                raise InputError(where, f"must be an object {{\"s\", \"albedo\", \"opacity\"}}, got {p!r}")
            check_keys(p, _POINT_KEYS, where)
            missing = [k for k in _POINT_KEYS if k not in p]
            if missing:
                raise InputError(where, f"missing {', '.join(repr(k) for k in missing)} (each point needs 's', "
                                 "'albedo' [r, g, b] and 'opacity')")
            try:
                s.append(float(p["s"]))
                alb.append([float(v) for v in p["albedo"]])
                opa.append(float(p["opacity"]))
            except (TypeError, ValueError):
                raise InputError(where, "needs numeric 's', 'albedo' [r, g, b] and 'opacity', got "
                                 f"{json.dumps(p)[:80]}") from None
            if len(alb[-1]) != 3:
                raise InputError(where, f"albedo must have three components [r, g, b], got {p['albedo']!r}")
        ds = _number(d, "density_scale", what, 50.0)
        return _relabelled(what, lambda: cls(np.array(s), np.array(alb), np.array(opa), ds,
                                             str(d.get("name", "custom"))))

    def save(self, path: str | Path, *, force: bool = False) -> None:
        """Write the points form (:meth:`to_dict`) as a TF file a scene can name (``"transfer_function":
        "tf.json"``), atomically; an existing file is replaced only with ``force``."""
        from photon_fields.runtime.io.atomic import atomic_path

        if Path(path).exists() and not force:
            raise InputError(str(path), "exists; pass force=True to replace it")
        with atomic_path(path) as tmp:
            Path(tmp).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @classmethod
    def load(cls, path: str | Path, volume: Volume | None = None) -> Any:
        """A transfer-function file (the JSON of :meth:`from_dict`; ``volume`` resolves ``{"preset": "auto"}``
        and ``{"preset": "labels"}`` and checks a labels form against the volume's labels)."""
        p = Path(path)
        if not p.is_file():
            raise InputError(str(p), "file not found")
        try:
            d = json.loads(p.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(str(p), f"not valid JSON ({exc})") from None
        return cls.from_dict(d, what=str(p), volume=volume)


def _auto(d: dict, what: str, volume: Volume | None) -> TransferFunction:
    """``{"preset": "auto"}`` resolved for ``volume``."""
    if volume is None:
        raise InputError(what, "preset 'auto' is keyed to a volume's histogram and needs the volume: use it in a "
                               "scene (or photon_fields.render), where the volume is known")
    from photon_fields.runtime.scene.auto_transfer import auto_transfer_function

    ds = _number(d, "density_scale", what) if "density_scale" in d else None
    return _relabelled(what, lambda: auto_transfer_function(volume, ds))


def _labels_preset(d: dict, what: str, volume: Volume | None) -> Any:
    """``{"preset": "labels"}`` (with optional ``visible`` and ``density_scale``) resolved for ``volume``."""
    check_keys(d, _LABELS_PRESET_KEYS, what)
    if volume is None:
        raise InputError(what, "preset 'labels' is built from the labels present in a volume and needs the volume: "
                               "use it in a scene (or photon_fields.render), where the volume is known")
    from photon_fields.runtime.scene.labels import DEFAULT_LABEL_DENSITY, labels_transfer

    ds = _number(d, "density_scale", what) if "density_scale" in d else DEFAULT_LABEL_DENSITY
    return labels_transfer(volume, d.get("visible"), density_scale=ds, what=what)


def _relabelled(what: str, build: Any) -> TransferFunction:
    """``build()``, with a validation error re-labelled by ``what`` (the scene entry or file the TF came
    from): the constructor's errors name only "transfer function 'custom'", which does not tell a user
    which file or scene entry is wrong."""
    try:
        return build()
    except InputError as err:
        raise InputError(what, err.problem) from None


def _number(d: dict, key: str, what: str, default: float | None = None) -> float:
    if key not in d:
        if default is None:
            raise InputError(what, f"missing '{key}'")
        return default
    try:
        return float(d[key])
    except (TypeError, ValueError):
        raise InputError(what, f"'{key}' must be a number, got {d[key]!r}") from None


def _tf(name: str, density: float, pts: list[tuple[float, tuple[float, float, float], float]]) -> TransferFunction:
    return TransferFunction(
        np.array([p[0] for p in pts]), np.array([p[1] for p in pts]), np.array([p[2] for p in pts]), density, name
    )


#: Built-in presets. Albedos stay high (0.8-0.95) because the point of the product is multiple scattering.
PRESETS: dict[str, TransferFunction] = {
    # Linear ramp, grey: a neutral default for any volume.
    "grey_ramp": _tf("grey_ramp", 60.0, [(0.0, (0.9, 0.9, 0.9), 0.0), (1.0, (0.9, 0.9, 0.9), 1.0)]),
    # Cloud: bright, nearly white, density rises quickly from a small threshold.
    "cloud": _tf("cloud", 80.0, [(0.0, (0.95, 0.95, 0.95), 0.0), (0.05, (0.95, 0.95, 0.95), 0.0),
                                 (0.4, (0.95, 0.95, 0.95), 0.7), (1.0, (0.95, 0.95, 0.95), 1.0)]),
    # Vortex: cool-to-warm colour by value, thin wisps stay translucent.
    "vortex": _tf("vortex", 120.0, [(0.0, (0.3, 0.5, 0.9), 0.0), (0.15, (0.3, 0.5, 0.9), 0.0),
                                    (0.4, (0.5, 0.8, 0.9), 0.3), (0.7, (0.95, 0.8, 0.5), 0.7),
                                    (1.0, (0.95, 0.5, 0.3), 1.0)]),
    # Shell: a solid-looking bone-white material for sharp-edged objects.
    "shell": _tf("shell", 200.0, [(0.0, (0.9, 0.85, 0.75), 0.0), (0.2, (0.9, 0.85, 0.75), 0.0),
                                  (0.3, (0.9, 0.85, 0.75), 0.6), (1.0, (0.85, 0.45, 0.35), 1.0)]),
    # CT: a sparse, classic medical TF for the head phantom's levels: CSF nearly clear, skin faint, brain
    # tissue translucent, vessels red and dense, bone opaque white.
    "ct": _tf("ct", 200.0, [(0.0, (0.85, 0.88, 0.9), 0.0), (0.08, (0.85, 0.88, 0.9), 0.0),
                            (0.12, (0.85, 0.88, 0.9), 0.01), (0.25, (0.95, 0.8, 0.7), 0.015),
                            (0.45, (0.93, 0.82, 0.76), 0.25), (0.75, (0.9, 0.35, 0.3), 0.8),
                            (1.0, (0.95, 0.93, 0.88), 1.0)]),
}


def preset(name: str, what: str = "transfer function") -> TransferFunction:
    """The built-in preset ``name`` (``auto`` is not one: it needs a volume, see :meth:`TransferFunction.from_dict`)."""
    if name in (AUTO, LABELS):
        raise InputError(what, f"preset '{name}' needs the volume: resolve it with TransferFunction.from_dict("
                               f"{{'preset': '{name}'}}, volume=...)")
    if name not in PRESETS:
        raise InputError(what, f"unknown preset '{name}' (available: {', '.join(sorted(PRESETS))}, {AUTO}, "
                               f"{LABELS})")
    return PRESETS[name]
