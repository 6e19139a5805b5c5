"""The photon field's input and output conventions (paper Sec. 3.1, 3.3.2, 3.4), shared by training and runtime.

numpy only (no torch): ``train.field.network`` has bit-identical torch twins of :func:`encode_radiance` and
:func:`decode_radiance` (tested), and the runtime evaluates a trained field with exactly these functions.

Output: the log target encoding (Eq. 6 / Eq. 7)
-----------------------------------------------
The field predicts the normalized radiance exponent ``L' = -log10(L) / psi`` instead of L (Eq. 6); values
``L <= 10^-psi`` are encoded as 1 (implicitly clamped to zero). Decoding is ``L = 10^(-L' psi)`` (Eq. 7),
so an encoded 1 decodes to ``10^-psi``, numerically zero next to the light the field carries. Eq. 6 maps
``(10^-psi, 1]`` to ``[0, 1)``; our targets Q can exceed 1 (small KNN radii on dense photon clusters: up
to ~100 measured), those map to negative L', which the linear output layer (no output activation,
Sec. 3.4) represents without trouble. Both functions compute in float64 and round to float32 once.

psi : float (``DEFAULT_PSI`` = 5)
    Decades of dynamic range below 1 that the encoding keeps. The paper found 4 to 6 sufficient. We chose
    5 from the targets themselves: Q at the final KNN radii (0.025 and 0.05 box units, K = 1024) at 30k
    points inside the support (sigma_t > 0, where the renderer queries the field) of the three embedded
    scenes with 1M-photon maps. The share of the total radiance carried by values at or below 10^-psi
    (what the clamp throws away) was at most 4.3e-4 for psi = 4 (shell), 1.2e-5 for psi = 5 and 2.1e-7
    for psi = 6. 1e-5 of the energy is invisible in any tone-mapped image, while every extra decade
    costs precision: an error e in the encoded output is a relative radiance error ``ln(10) psi e``, so
    psi = 6 would make the same network error 20 % larger in radiance than psi = 5, to represent light
    nobody can see.

Inputs (Sec. 3.1, Eq. 2: ``P(x, g, omega)``)
--------------------------------------------
- position: :func:`normalize_position`, world box ``[bmin, bmin + bsize]`` -> ``[0, 1]^3`` per axis (the
  paper's grid coordinates; non-cubic boxes are stretched to the unit cube, so every grid level covers
  the whole volume with no unused table entries);
- direction: :func:`direction_input`, the camera ray's unit *travel* direction d (the direction the
  radiance estimate Q(x, d, g) of :mod:`photon_fields.runtime.photons.estimate` is queried with, light arriving at the
  camera travels along -d) -> :func:`photon_fields.models_spec.hashgrid.direction_to_unit_square` (normalized
  spherical coordinates, as in Sec. 3.1);
- phase: :func:`phase_features`: g in [-1, 1] unencoded ("a unitless scale", Sec. 3.4), followed, with the
  ``"tent"`` phase encoding, by one tent function per phase of G: the weight of G_j in the piecewise-linear
  interpolation over the sorted phases (1 at G_j, falling to 0 at its neighbours, constant beyond the ends).
  Why: the MLP has no biases, so from g alone it can bend its output in g only where position and direction
  features happen to cancel; trained on several phases, such a field tilts across g (a few to 10 % bright at
  one end of G and dark at the other, where its photon map is right at every g; bench/README.md). The tents give
  it a kink at every phase. With the ``"spline"`` encoding, by the uniform cubic B-spline weights of g on the
  phases (which must then be evenly spaced, h apart): B((g - G_j) / h) with B the cubic B-spline kernel
  (2/3 - t^2 + |t|^3 / 2 for |t| < 1, (2 - |t|)^3 / 6 for |t| < 2), the weights of the two nodes just outside
  G added to the end nodes, g clamped to [min G, max G]; they sum to 1 there. Why not tents: the first layer
  of a tent field is linear in g between two nodes, and a least-squares line through a curved stretch is off
  in one direction at its ends and in the other in the middle: trained on every g, a tent field was 2-4 %
  darker at each node than half-way between (docs/training.md). The splines are smooth (C2) and give the
  first layer a cubic in g between nodes.

With ``direction_gain`` "g" the direction features enter the MLP multiplied by g (:func:`direction_gains`). Why:
the in-scattered light is isotropic at g = 0 whatever the incident light (the l-th Legendre coefficient of the
Henyey-Greenstein phase function is g^l, so its direction dependence is of first order in g), and a field whose
direction features enter unscaled has to learn that by cancelling them with the phase features, and fitted fields
did not quite: they came out darker towards some directions than others at g = 0, and dark in the image there
(docs/training.md). Scaled by g, the field is isotropic at g = 0 exactly, and its direction dependence starts at
first order in g, as the light's does; the sign of g (forward or back scattering) reaches it too.

With ``surface`` set, two columns from the medium's surface orientation at x, seen along d, follow
(:mod:`photon_fields.models_spec.surface`, which says why).

The network input is ``[hash_position(x) (Lp Fp), hash_direction(d) (Ld Fd), phase features (1 or 1 + |G|),
surface columns (0 or 2)]`` in this order.

:class:`FieldConfig` (what a trained field needs to be rebuilt)
---------------------------------------------------------------
position : HashGridConfig (dims 3), direction : HashGridConfig (dims 2)
    The two hash encodings (paper: 16 levels x 8 features, 2x scale, 2^19 tables).
hidden_width : int >= 1, hidden_layers : int >= 1
    ReLU MLP: ``hidden_layers`` hidden layers of ``hidden_width`` neurons, i.e. ``hidden_layers + 1``
    linear layers, no biases (tiny-cuda-nn's FullyFusedMLP has none), no output activation, 3 outputs.
    The paper's "5-layer perceptron with 64 neurons" is ``hidden_layers = 4, hidden_width = 64``.
psi : float in (0, 30]
    Eq. 6 / 7 precision (above).
phases : tuple of g in [-1, 1]
    The phase set G the field was trained on (the photon map's); g between them is interpolated.
phase_encoding : "scalar" (default, the paper), "tent" or "spline"
    The phase features (above); "spline" needs two or more evenly spaced, increasing phases. A "scalar"
    config's dict has no ``phase_encoding`` key, so configs written before it existed read unchanged.
direction_gain : "none" (default, the paper) or "g"
    Whether the direction features are multiplied by g (above); like ``phase_encoding``, a key of the dict only
    when it is not the default.
surface : (sx, sy, sz) or None (default, the paper)
    The surface input's grid cells (:mod:`photon_fields.models_spec.surface`); a key of the dict only when set.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from photon_fields.models_spec.hashgrid import PAPER_DIRECTION, PAPER_POSITION, HashGridConfig, direction_to_unit_square
from photon_fields.models_spec.photon_map import DEFAULT_PHASES
from photon_fields.models_spec.surface import SURFACE_COLUMNS, SURFACE_MAX_CELLS

DEFAULT_PSI = 5.0
FIELD_CONFIG_VERSION = 1
#: The phase encodings a FieldConfig may name (module docstring).
PHASE_ENCODINGS = ("scalar", "tent", "spline")
#: Largest departure from even spacing the "spline" encoding accepts in its phases (they are stored rounded).
SPLINE_SPACING_TOLERANCE = 1e-5
#: What the direction features may be multiplied by before the MLP (:attr:`FieldConfig.direction_gain`).
DIRECTION_GAINS = ("none", "g")
#: Output channels per light: RGB.
OUTPUT_CHANNELS = 3
#: Most lights a field keeps apart (:attr:`FieldConfig.light_channels`); a scene with more trains one summed output.
MAX_LIGHT_CHANNELS = 16


def check_psi(psi: float) -> float:
    p = float(psi)
    if not (0.0 < p <= 30.0):  # 10^-30 still fits float32's range with room; NaN fails too
        raise ValueError(f"psi must be in (0, 30], got {psi!r}")
    return p


def encode_radiance(L: np.ndarray, psi: float = DEFAULT_PSI) -> np.ndarray:
    """Eq. 6: float32 ``-log10(L) / psi`` where ``L > 10^-psi``, else 1 (zero, negative, NaN included)."""
    p = check_psi(psi)
    lum = np.asarray(L, dtype=np.float64)
    keep = lum > 10.0**-p  # False for NaN: a broken estimate reads as "no light", never as NaN
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(keep, -np.log10(np.where(keep, lum, 1.0)) / p, 1.0)
    return out.astype(np.float32)


def decode_radiance(Lp: np.ndarray, psi: float = DEFAULT_PSI) -> np.ndarray:
    """Eq. 7: float32 ``10^(-L' psi)``. Not clamped: ``L' > 1`` decodes below ``10^-psi`` (darker still)."""
    p = check_psi(psi)
    with np.errstate(over="ignore"):
        return np.power(10.0, -np.asarray(Lp, dtype=np.float64) * p).astype(np.float32)


def box_arguments(x_world: np.ndarray, bmin: np.ndarray, bsize: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`normalize_position`'s arguments checked and as float64: x (n, 3), bmin (3,), bsize (3,) (also what
    the runtime's numba twin, ``runtime.field.inputs.normalized_positions``, computes from)."""
    x = np.asarray(x_world, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x_world must have shape (n, 3), got {x.shape}")
    lo = np.asarray(bmin, dtype=np.float64).reshape(3)
    size = np.asarray(bsize, dtype=np.float64).reshape(3)
    if not np.all(size > 0):
        raise ValueError(f"bsize must be positive, got {size}")
    return x, lo, size


def normalize_position(x_world: np.ndarray, bmin: np.ndarray, bsize: np.ndarray) -> np.ndarray:
    """World positions (n, 3) -> float32 (n, 3) in [0, 1]^3: ``(x - bmin) / bsize`` per axis (float64, then
    one rounding). Points outside the box map outside [0, 1] (the hash grid accepts them)."""
    x, lo, size = box_arguments(x_world, bmin, bsize)
    return ((x - lo) / size).astype(np.float32)


def direction_input(d: np.ndarray) -> np.ndarray:
    """Camera-ray unit travel directions (n, 3) -> float32 (n, 2) in [0, 1]^2, the direction encoding's input."""
    return direction_to_unit_square(d)


def phase_input(g: np.ndarray | float, n: int | None = None) -> np.ndarray:
    """Phase coefficients -> float32 (n, 1) (a scalar g is repeated ``n`` times)."""
    ga = np.asarray(g, dtype=np.float32)
    if ga.ndim == 0:
        if n is None:
            raise ValueError("phase_input: give n for a scalar g")
        ga = np.full(n, ga, dtype=np.float32)
    return ga.reshape(-1, 1)


def cubic_bspline(t: np.ndarray) -> np.ndarray:
    """The uniform cubic B-spline kernel B(t): 2/3 - t^2 + |t|^3 / 2 for |t| < 1, (2 - |t|)^3 / 6 for
    |t| < 2, else 0. Its integer shifts sum to 1 and it is twice continuously differentiable."""
    a = np.abs(t)
    return np.where(a < 1.0, 2.0 / 3.0 - a * a + 0.5 * a * a * a, np.where(a < 2.0, (2.0 - a) ** 3 / 6.0, 0.0))


def check_spline_phases(phases: tuple[float, ...]) -> None:
    """Refuse phases the "spline" encoding cannot use: fewer than two, not increasing or not evenly spaced."""
    p = np.asarray(phases, dtype=np.float64)
    if p.size < 2 or not np.all(np.diff(p) > 0):
        raise ValueError(f"the spline phase encoding needs two or more increasing phases, got {tuple(phases)}")
    h = (p[-1] - p[0]) / (p.size - 1)
    if np.max(np.abs(p - (p[0] + h * np.arange(p.size)))) > SPLINE_SPACING_TOLERANCE:
        raise ValueError(f"the spline phase encoding needs evenly spaced phases, got {tuple(phases)}")


def _spline_weights(g: np.ndarray, phases: tuple[float, ...]) -> np.ndarray:
    """(n, |G|) cubic B-spline weights of g on the evenly spaced phases (module docstring): B(t - j) for node j, t
    = g in node units, with the nodes one spacing outside G (j = -1 and |G|) folded into the end columns. B vanishes
    for |t - j| >= 2, so only the four nodes floor(t) - 1 .. floor(t) + 2 are evaluated (a fit needs a batch's
    weights every step: all 16 nodes everywhere took a quarter of a training step); the values are bit for bit
    B's at every node (tests/models_spec/test_encoding.py)."""
    p = np.asarray(phases, dtype=np.float64)
    h = (p[-1] - p[0]) / (p.size - 1)
    t = (np.clip(g, p[0], p[-1]) - p[0]) / h  # g in node units, in [0, |G| - 1] (NaN stays NaN: a row of zeros)
    first = np.floor(np.where(np.isfinite(t), t, 0.0)).astype(np.int64) - 1
    nodes = first[:, None] + np.arange(4)[None, :]  # in [-1, |G| + 1]
    around = np.zeros((t.shape[0], p.size + 3))  # nodes -1 .. |G| + 1 in columns 0 .. |G| + 2
    np.put_along_axis(around, nodes + 1, cubic_bspline(t[:, None] - nodes), axis=1)
    w = around[:, 1:p.size + 1].copy()
    w[:, 0] += around[:, 0]  # the node at min G - h, outside G
    w[:, -1] += around[:, p.size + 1]  # the node at max G + h
    return w


def phase_features(g: np.ndarray, phases: tuple[float, ...], encoding: str) -> np.ndarray:
    """Phase coefficients (n,) -> float32 (n, 1) for ``"scalar"``, (n, 1 + |G|) for ``"tent"`` and ``"spline"``:
    g, then the tent (or cubic B-spline) weight of each phase in the order of ``phases`` (module docstring).
    The weights of a g sum to 1."""
    ga = np.asarray(g, dtype=np.float64).reshape(-1)
    if encoding == "scalar":
        return ga.astype(np.float32).reshape(-1, 1)
    if encoding not in PHASE_ENCODINGS:
        raise ValueError(f"unknown phase encoding {encoding!r} (one of {PHASE_ENCODINGS})")
    if ga.shape[0] > 1 and (ga == ga[0]).all():  # one g for the whole batch (a rendered frame): one row
        return np.repeat(phase_features(ga[:1], phases, encoding), ga.shape[0], axis=0)
    out = np.empty((ga.shape[0], 1 + len(phases)), np.float32)
    out[:, 0] = ga
    if encoding == "spline":
        check_spline_phases(phases)
        out[:, 1:] = _spline_weights(ga, phases)
        return out
    order = np.argsort(np.asarray(phases, dtype=np.float64), kind="stable")
    sorted_g = np.asarray(phases, dtype=np.float64)[order]
    for rank, j in enumerate(order):
        unit = np.zeros(len(phases))
        unit[rank] = 1.0
        out[:, 1 + j] = np.interp(ga, sorted_g, unit) if len(phases) > 1 else 1.0
    return out


def direction_gains(g: np.ndarray, gain: str) -> np.ndarray | None:
    """The factors (n, 1) float32 the direction features of phase coefficients g (n,) are multiplied by before
    the MLP: g itself for ``gain`` "g" (module docstring), None for "none" (the features as they are)."""
    if gain == "none":
        return None
    if gain not in DIRECTION_GAINS:
        raise ValueError(f"unknown direction gain {gain!r} (one of {DIRECTION_GAINS})")
    return np.asarray(g, dtype=np.float32).reshape(-1, 1)


def _int_field(name: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)) or not lo <= int(v) <= hi:
        raise ValueError(f"FieldConfig.{name} must be an int in [{lo}, {hi}], got {v!r}")
    return int(v)


#: FieldConfig keys a dict may leave out (their defaults: configs written before they existed read unchanged).
_OPTIONAL_KEYS = ("phase_encoding", "light_channels", "direction_gain", "surface")


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of a photon field (see the module docstring)."""

    position: HashGridConfig = PAPER_POSITION
    direction: HashGridConfig = PAPER_DIRECTION
    hidden_width: int = 64
    hidden_layers: int = 4
    psi: float = DEFAULT_PSI
    phases: tuple[float, ...] = DEFAULT_PHASES
    phase_encoding: str = "scalar"
    light_channels: int = 1
    """Lights whose parts of L the field outputs apart (RGB each, light l's in output columns 3 l .. 3 l + 2, the
    scene's lights in order): 1, the paper's single RGB output for all lights together; or the scene's number of
    lights, so that one light's power or colour can be rescaled among several without retraining (the renderer sums
    the parts, each times its light's factor). Written to the manifest only when > 1: bundles of one output are
    unchanged."""
    direction_gain: str = "none"
    """"none" (the paper) or "g": the direction features times g (module docstring; :func:`direction_gains`)."""
    surface: tuple[int, int, int] | None = None
    """The surface input's grid cells (sx, sy, sz), or None (the paper) for a field without it
    (:mod:`photon_fields.models_spec.surface`): its :data:`photon_fields.models_spec.surface.SURFACE_COLUMNS` columns
    come last in the MLP input, and the bundle's ``tables.npz`` holds the grid as ``surface``."""

    def __post_init__(self) -> None:
        if not isinstance(self.position, HashGridConfig) or self.position.dims != 3:
            raise ValueError(f"FieldConfig.position must be a 3-D HashGridConfig, got {self.position!r}")
        if not isinstance(self.direction, HashGridConfig) or self.direction.dims != 2:
            raise ValueError(f"FieldConfig.direction must be a 2-D HashGridConfig, got {self.direction!r}")
        object.__setattr__(self, "hidden_width", _int_field("hidden_width", self.hidden_width, 1, 4096))
        object.__setattr__(self, "hidden_layers", _int_field("hidden_layers", self.hidden_layers, 1, 64))
        object.__setattr__(self, "psi", check_psi(self.psi))
        object.__setattr__(self, "light_channels", _int_field("light_channels", self.light_channels, 1,
                                                              MAX_LIGHT_CHANNELS))
        try:
            phases = tuple(float(g) for g in self.phases)
        except (TypeError, ValueError):
            raise ValueError(f"FieldConfig.phases must be numbers in [-1, 1], got {self.phases!r}") from None
        if not phases or not all(-1.0 <= g <= 1.0 and math.isfinite(g) for g in phases):
            raise ValueError(f"FieldConfig.phases must be a non-empty set of g in [-1, 1], got {self.phases!r}")
        object.__setattr__(self, "phases", phases)
        if self.phase_encoding not in PHASE_ENCODINGS:
            raise ValueError(f"FieldConfig.phase_encoding must be one of {PHASE_ENCODINGS}, "
                             f"got {self.phase_encoding!r}")
        if self.direction_gain not in DIRECTION_GAINS:
            raise ValueError(f"FieldConfig.direction_gain must be one of {DIRECTION_GAINS}, "
                             f"got {self.direction_gain!r}")
        if self.surface is not None:
            try:
                cells = tuple(int(c) for c in self.surface)
                ok = len(cells) == 3 and all(not isinstance(c, bool) and c == int(c) for c in self.surface)
            except (TypeError, ValueError):
                ok = False
            if not ok or not all(1 <= c <= SURFACE_MAX_CELLS for c in cells):
                raise ValueError(f"FieldConfig.surface must be three cell counts in [1, {SURFACE_MAX_CELLS}] or None, "
                                 f"got {self.surface!r}")
            object.__setattr__(self, "surface", cells)
        if self.phase_encoding == "spline":
            try:
                check_spline_phases(phases)
            except ValueError as e:
                raise ValueError(f"FieldConfig.phases: {e}") from None

    @property
    def phase_dims(self) -> int:
        """Columns of :func:`phase_features`: 1, or 1 + |G| with the tent or spline encoding."""
        return 1 + (len(self.phases) if self.phase_encoding != "scalar" else 0)

    @property
    def output_dims(self) -> int:
        """MLP output width: RGB per light channel."""
        return OUTPUT_CHANNELS * self.light_channels

    @property
    def surface_dims(self) -> int:
        """Columns of the surface input: :data:`photon_fields.models_spec.surface.SURFACE_COLUMNS`, or 0."""
        return SURFACE_COLUMNS if self.surface is not None else 0

    @property
    def input_dims(self) -> int:
        """MLP input width: position features + direction features + phase features + surface columns."""
        return self.position.output_dims + self.direction.output_dims + self.phase_dims + self.surface_dims

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (nested hash-grid dicts), with a format version."""
        out = {"version": FIELD_CONFIG_VERSION, "position": self.position.to_dict(),
               "direction": self.direction.to_dict(), "hidden_width": self.hidden_width,
               "hidden_layers": self.hidden_layers, "psi": self.psi, "phases": list(self.phases)}
        if self.phase_encoding != "scalar":
            out["phase_encoding"] = self.phase_encoding
        if self.light_channels != 1:
            out["light_channels"] = self.light_channels
        if self.direction_gain != "none":
            out["direction_gain"] = self.direction_gain
        if self.surface is not None:
            out["surface"] = list(self.surface)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> FieldConfig:
        """Inverse of :meth:`to_dict`; unknown or missing keys, or another version, raise ValueError."""
        if not isinstance(data, Mapping):
            raise ValueError(f"FieldConfig.from_dict needs a mapping, got {type(data).__name__}")
        if data.get("version") != FIELD_CONFIG_VERSION:
            raise ValueError(f"FieldConfig version {data.get('version')!r} is not supported "
                             f"(this build reads version {FIELD_CONFIG_VERSION})")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names) - {"version"})
        missing = [n for n in names if n not in data and n not in _OPTIONAL_KEYS]
        if unknown or missing:
            raise ValueError(f"FieldConfig.from_dict: unknown keys {unknown}, missing keys {missing}")
        return cls(position=HashGridConfig.from_dict(data["position"]),
                   direction=HashGridConfig.from_dict(data["direction"]), hidden_width=data["hidden_width"],
                   hidden_layers=data["hidden_layers"], psi=data["psi"], phases=tuple(data["phases"]),
                   phase_encoding=data.get("phase_encoding", "scalar"), light_channels=data.get("light_channels", 1),
                   direction_gain=data.get("direction_gain", "none"),
                   surface=None if data.get("surface") is None else tuple(data["surface"]))
