"""Photon maps in memory and on disk (format: :mod:`photon_fields.models_spec.photon_map`).

:class:`PhotonMap` holds the records of multi-phase photon tracing (paper Alg. 1, produced by
``photon_fields.train.photons.tracing``): position, incoming travel direction, RGB power and phase index of every
photon at its second or later collision. ``save`` writes atomically; ``load`` refuses files of another
format or version, from another scene, or with inconsistent arrays, with a one-line
:class:`photon_fields.runtime.errors.InputError`.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.fingerprint import FINGERPRINT_PARTS, mismatch_detail
from photon_fields.models_spec.npz_manifest import ArrayHeaders
from photon_fields.models_spec.photon_map import (
    PHOTON_MAP_ARRAYS,
    PHOTON_MAP_FORMAT,
    PHOTON_MAP_NPZ,
    PHOTON_MAP_OPTIONAL_ARRAYS,
    PHOTON_MAP_VERSION,
)
from photon_fields.runtime.errors import InputError, check_keys, npz_errors_as_input
from photon_fields.runtime.io.atomic import atomic_path

_SHA256 = re.compile(r"^[0-9a-f]{64}$")


def find_phase(phases: Sequence[float], g: float) -> int | None:
    """Index of ``g`` in a phase set (within 1e-6), or None: the one membership rule for maps and fields."""
    for i, gi in enumerate(phases):
        if abs(gi - g) < 1e-6:
            return i
    return None


@dataclass(eq=False)
class PhotonMap:
    position: np.ndarray  # float32 (n, 3)
    direction: np.ndarray  # float32 (n, 3)
    power: np.ndarray  # float32 (n, 3)
    phase: np.ndarray  # uint8 (n,)
    phases: tuple[float, ...]
    scene_fingerprint: str
    emitted: int
    meta: dict[str, Any] = field(default_factory=dict)
    #: The file it was loaded from (None for a map in memory): names the map in messages.
    path: Path | None = None
    #: uint8 (n,): the index into :attr:`lights` of the light each record's path started from, or None (a map traced
    #: before maps recorded it): what keeps the lights' contributions apart (a field's ``light_channels``).
    light: np.ndarray | None = None
    #: uint8 (n,) and float32 (n,), or None (maps traced before them): each record's collision number along its path
    #: (2, 3, ...; a path's records are consecutive) and the scalar at the path's previous collision, with which an
    #: edit of the albedo alone reweights the map (:mod:`photon_fields.runtime.photons.albedo_reweight`).
    bounce: np.ndarray | None = None
    prev_scalar: np.ndarray | None = None

    def optional_arrays(self) -> dict[str, np.ndarray]:
        """The optional per-record arrays the map holds (of :data:`photon_fields.models_spec.photon_map.
        PHOTON_MAP_OPTIONAL_ARRAYS`), by name: what a copy of some of its records takes along."""
        return {name: getattr(self, name) for name in PHOTON_MAP_OPTIONAL_ARRAYS if getattr(self, name) is not None}

    @property
    def light_count(self) -> int:
        """How many lights the records can be told apart by: the recorded lights' number with a ``light`` array,
        else 1 (every record counts for all lights together)."""
        return len(self.lights or ()) if self.light is not None else 1

    @property
    def scene_parts(self) -> dict[str, str] | None:
        """Per-part fingerprints of the scene traced for (``meta["scene_parts"]``), None for older maps."""
        parts = self.meta.get("scene_parts")
        return dict(parts) if isinstance(parts, dict) else None

    @property
    def record_floor(self) -> float:
        """The record floor q the map was traced with (``meta["record_floor"]``, 0 for a map without one): what
        its records' weights divide by (:func:`photon_fields.runtime.photons.photon_path.record_densities`)."""
        return float(self.meta.get("record_floor", 0.0))

    @property
    def lights(self) -> list[dict[str, Any]] | None:
        """The lights traced with, as the scene's fingerprint hashes them (``meta["lights"]``), None for older maps."""
        lights = self.meta.get("lights")
        return list(lights) if isinstance(lights, list) else None

    def rescaled(self, scale: np.ndarray, scene: Any) -> PhotonMap:
        """This map for ``scene``, whose lights are the traced ones with their flux times ``scale`` (RGB (3,), from
        :func:`photon_fields.runtime.scene.light_rescale.flux_rescale`, or one RGB factor per light (L, 3) for a map
        with a ``light`` array): every record's power times its light's factor, which is what tracing ``scene``
        with the same seed gives (the same paths); the positions and directions are shared."""
        meta = {**self.meta, "scene_parts": scene.fingerprint_parts(), "lights": scene.light_identities()}
        factor = np.asarray(scale, dtype=np.float32)
        if factor.ndim == 2:
            factor = factor[self.light] if self.light is not None else factor.reshape(3)
        power = (self.power * factor).astype(np.float32)
        return PhotonMap(self.position, self.direction, power, self.phase, self.phases, scene.fingerprint(),
                         self.emitted, meta, self.path, **self.optional_arrays())

    def __len__(self) -> int:
        return int(self.position.shape[0])

    def phase_index(self, g: float, what: str = "g") -> int:
        """Index of ``g`` in the map's phase set; the estimate is phase-selective (Eq. 5), so a g that
        was not traced cannot be answered by the map."""
        i = find_phase(self.phases, g)
        if i is None:
            raise InputError(what, f"g = {g} is not in the photon map's phase set {list(self.phases)}")
        return i

    def subset(self, phase: int) -> PhotonMap:
        sel = self.phase == phase
        return PhotonMap(self.position[sel], self.direction[sel], self.power[sel], self.phase[sel], self.phases,
                         self.scene_fingerprint, self.emitted, dict(self.meta), self.path,
                         **{name: a[sel] for name, a in self.optional_arrays().items()})

    def metadata(self) -> dict[str, Any]:
        counts = np.bincount(self.phase, minlength=len(self.phases)) if len(self) else np.zeros(len(self.phases))
        return {**self.meta, "format": PHOTON_MAP_FORMAT, "version": PHOTON_MAP_VERSION,
                "scene_fingerprint": self.scene_fingerprint, "phases": list(self.phases), "emitted": int(self.emitted),
                "stored": len(self), "per_phase": [int(c) for c in counts]}

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        meta = np.frombuffer(json.dumps(self.metadata()).encode(), dtype=np.uint8)
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, position=self.position, direction=self.direction, power=self.power, phase=self.phase,
                     meta=meta, **self.optional_arrays())
        return path

    @classmethod
    def load(cls, path: str | Path, expected_fingerprint: str | None = None,
             expected_parts: dict[str, str] | None = None) -> PhotonMap:
        """Load and validate; with ``expected_fingerprint`` also refuse a map traced for another scene
        (``expected_parts``, the scene's :meth:`runtime.scene.scene.Scene.fingerprint_parts`, names what differs)."""
        p = Path(path)
        what = str(p)
        if not p.is_file():
            raise InputError(what, "photon map file not found")
        with npz_errors_as_input():
            meta, arrays = PHOTON_MAP_NPZ.read(p)
        n = _check_arrays({k: (a.shape, a.dtype) for k, a in arrays.items()}, what)
        phases, fp, emitted = _check_meta_values(meta, what)
        if n and int(arrays["phase"].max()) >= len(phases):
            raise InputError(what, "phase index out of range of the phase set")
        light = arrays.get("light")
        if light is not None:
            lights = meta.get("lights")
            if not isinstance(lights, list) or (n and int(light.max()) >= len(lights)):
                raise InputError(what, "'light' indexes lights the metadata does not list")
        if "stored" in meta and meta["stored"] != n:
            raise InputError(f"{what} metadata", f"'stored' is {meta['stored']!r} but the arrays hold {n} photons")
        for name in ("position", "direction", "power"):
            if not np.all(np.isfinite(arrays[name])):
                raise InputError(what, f"'{name}' contains non-finite values")
        if ("bounce" in arrays) != ("prev_scalar" in arrays):
            raise InputError(what, "holds one of 'bounce' and 'prev_scalar' without the other")
        if "bounce" in arrays and n and (int(arrays["bounce"].min()) < 2 or not np.all(np.isfinite(
                arrays["prev_scalar"]))):
            raise InputError(what, "'bounce' below 2 (records start at a path's 2nd collision) or a non-finite "
                             "'prev_scalar'")
        pmap = cls(arrays["position"], arrays["direction"], arrays["power"], arrays["phase"], phases, fp, emitted,
                   meta, p, **{name: arrays[name] for name in PHOTON_MAP_OPTIONAL_ARRAYS if name in arrays})
        if expected_fingerprint is not None and fp != expected_fingerprint:
            raise InputError(what, f"photon map was traced for {pmap.mismatch(expected_parts)}; re-trace it for "
                             "this scene")
        return pmap

    def mismatch(self, expected_parts: dict[str, str] | None) -> str:
        """``"another scene ('blobs'): lights differ (volume and transfer function match)"``: the scene this
        map was traced for (by name, when recorded) and what differs from a scene with ``expected_parts``."""
        name = self.meta.get("scene_name")
        named = f" ({name!r})" if isinstance(name, str) and name else ""
        return f"another scene{named}: {mismatch_detail(expected_parts, self.scene_parts)}"


@dataclass(frozen=True)
class PhotonMapHeader:
    """What a photon map file says about itself without its photons (:func:`read_header`): the checked
    metadata, the record count and the file. ``pfn-train update`` needs the earlier map's seed, phases, max
    bounces and size, not its 5M records (~185 MB, ~2 s to load and check)."""

    path: Path
    meta: dict[str, Any]
    phases: tuple[float, ...]
    scene_fingerprint: str
    emitted: int
    count: int
    #: As :attr:`PhotonMap.light_count`: the recorded lights' number when the file has a ``light`` array, else 1.
    light_count: int = 1

    @property
    def scene_parts(self) -> dict[str, str] | None:
        parts = self.meta.get("scene_parts")
        return dict(parts) if isinstance(parts, dict) else None


def read_header(path: str | Path, expected_fingerprint: str | None = None) -> PhotonMapHeader:
    """The metadata and record count of the photon map at ``path``, read from the ``meta`` entry and the
    arrays' ``.npy`` headers only (no photon is read). The checks :meth:`PhotonMap.load` makes on the metadata
    and the arrays' names, dtypes and shapes are made here too (the per-photon ones, finite values and phase
    indices in range, need the photons and are left to the load); one-line errors naming the file."""
    p = Path(path)
    what = str(p)
    if not p.is_file():
        raise InputError(what, "photon map file not found")
    with npz_errors_as_input():
        meta, shapes = PHOTON_MAP_NPZ.read_headers(p)
    n = _check_arrays(shapes, what)
    phases, fp, emitted = _check_meta_values(meta, what)
    if "stored" in meta and meta["stored"] != n:
        raise InputError(f"{what} metadata", f"'stored' is {meta['stored']!r} but the arrays hold {n} photons")
    if expected_fingerprint is not None and fp != expected_fingerprint:
        name = meta.get("scene_name")
        named = f" ({name!r})" if isinstance(name, str) and name else ""
        parts = meta.get("scene_parts")
        raise InputError(what, f"photon map was traced for another scene{named}: "
                         f"{mismatch_detail(None, parts if isinstance(parts, dict) else None)}; re-trace it for "
                         "this scene")
    lights = meta.get("lights")
    apart = len(lights) if "light" in shapes and isinstance(lights, list) else 1
    return PhotonMapHeader(p, meta, phases, fp, emitted, int(n or 0), apart)


def _check_arrays(shapes: ArrayHeaders, what: str) -> int | None:
    """The arrays of a map (name -> (shape, dtype), ``meta`` left out, names checked by
    :data:`PHOTON_MAP_NPZ`): each of its dtype and width, all with one row count, which is returned (None without
    arrays). One-line errors naming ``what``; shared by :meth:`PhotonMap.load` and :func:`read_header`, which reads
    only the ``.npy`` headers."""
    n = None
    for name, (dtype, width) in {**PHOTON_MAP_ARRAYS, **PHOTON_MAP_OPTIONAL_ARRAYS}.items():
        if name not in shapes:
            continue  # an optional array (the required ones are checked by PHOTON_MAP_NPZ)
        shape, found = tuple(shapes[name][0]), np.dtype(shapes[name][1])
        if found != np.dtype(dtype) or len(shape) != (2 if width else 1) or (width and shape[1] != width):
            expected = f"(n, {width})" if width else "(n,)"
            raise InputError(what, f"'{name}' has dtype {found} shape {shape}, expected {dtype} {expected}")
        if n is None:
            n = shape[0]
        elif shape[0] != n:
            raise InputError(what, f"'{name}' has {shape[0]} rows, expected {n}")
    return n


def _check_meta_values(meta: dict[str, Any], what: str) -> tuple[tuple[float, ...], str, int]:
    """Phases, scene fingerprint and emitted count of checked metadata (and its scene parts, if any)."""
    try:
        phases = tuple(float(g) for g in meta["phases"])
    except (TypeError, ValueError):
        raise InputError(f"{what} metadata", f"'phases' must be a list of numbers, got {meta['phases']!r}"
                         ) from None
    if not phases:
        raise InputError(what, "photon map metadata lists no phases")
    fp = meta["scene_fingerprint"]
    if not isinstance(fp, str) or not _SHA256.match(fp):
        raise InputError(f"{what} metadata", f"'scene_fingerprint' must be a sha256 hex string, got {fp!r}")
    if "scene_parts" in meta:
        _check_parts(meta["scene_parts"], f"{what} metadata scene_parts")
    check_record_floor(meta.get("record_floor", 0.0), f"{what} metadata 'record_floor'")
    emitted = meta["emitted"]
    if isinstance(emitted, bool) or not isinstance(emitted, int) or emitted <= 0:
        raise InputError(what, f"photon map metadata has no positive 'emitted' count (got {emitted!r})")
    return phases, fp, emitted


def check_record_floor(q: Any, what: str = "record_floor") -> float:
    """A record floor (:mod:`photon_fields.runtime.photons.photon_path`): a number in [0, 1), as a float; one line
    naming ``what`` otherwise. The one check of a map's metadata and of tracing's argument."""
    if isinstance(q, bool) or not isinstance(q, (int, float, np.floating)) or not 0.0 <= q < 1.0:
        raise InputError(what, f"must be a number in [0, 1), got {q!r}")
    return float(q)


def _check_parts(parts: Any, what: str) -> None:
    if not isinstance(parts, dict):
        raise InputError(what, f"must be an object with keys {', '.join(FINGERPRINT_PARTS)}")
    check_keys(parts, FINGERPRINT_PARTS, what, required=FINGERPRINT_PARTS)
    for key, value in parts.items():
        if not isinstance(value, str) or not _SHA256.match(value):
            raise InputError(f"{what} {key}", f"must be a sha256 hex string, got {value!r}")
