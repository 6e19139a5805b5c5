"""Photon maps in memory and on disk (format: :mod:`models_spec.photon_map`).

:class:`PhotonMap` holds the records of multi-phase photon tracing (paper Alg. 1, produced by
``train.photon_tracing``): position, incoming travel direction, RGB power and phase index of every
photon at its second or later collision. ``save`` writes atomically; ``load`` refuses files of another
format or version, from another scene, or with inconsistent arrays, with a one-line
:class:`runtime.errors.InputError`.
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from models_spec.photon_map import PHOTON_MAP_ARRAYS, PHOTON_MAP_FORMAT, PHOTON_MAP_VERSION
from runtime.atomic import atomic_path
from runtime.errors import InputError


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
                         self.scene_fingerprint, self.emitted, dict(self.meta))

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
                     meta=meta)
        return path

    @classmethod
    def load(cls, path: str | Path, expected_fingerprint: str | None = None) -> PhotonMap:
        """Load and validate; with ``expected_fingerprint`` also refuse a map traced for another scene."""
        p = Path(path)
        what = str(p)
        if not p.is_file():
            raise InputError(what, "photon map file not found")
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
            raise InputError(what, f"not a readable photon map (.npz): {exc}") from None
        if "meta" not in arrays:
            raise InputError(what, "not a photon map: no 'meta' entry")
        try:
            meta = json.loads(arrays.pop("meta").tobytes().decode())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise InputError(what, f"corrupt photon map metadata ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != PHOTON_MAP_FORMAT:
            found = meta.get("format") if isinstance(meta, dict) else None
            raise InputError(what, f"not a photon map (format {found!r}, expected {PHOTON_MAP_FORMAT!r})")
        if meta.get("version") != PHOTON_MAP_VERSION:
            raise InputError(what, f"photon map version {meta.get('version')!r} is not supported "
                             f"(this build reads version {PHOTON_MAP_VERSION}); re-trace it")
        n = None
        for name, (dtype, width) in PHOTON_MAP_ARRAYS.items():
            if name not in arrays:
                raise InputError(what, f"photon map lacks the '{name}' array")
            a = arrays[name]
            shape_ok = a.ndim == (2 if width else 1) and (not width or a.shape[1] == width)
            if a.dtype != np.dtype(dtype) or not shape_ok:
                expected = f"(n, {width})" if width else "(n,)"
                raise InputError(what, f"'{name}' has dtype {a.dtype} shape {a.shape}, expected {dtype} {expected}")
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise InputError(what, f"'{name}' has {a.shape[0]} rows, expected {n}")
        phases = tuple(float(g) for g in meta.get("phases", []))
        if not phases:
            raise InputError(what, "photon map metadata lists no phases")
        if n and int(arrays["phase"].max()) >= len(phases):
            raise InputError(what, "phase index out of range of the phase set")
        for name in ("position", "direction", "power"):
            if not np.all(np.isfinite(arrays[name])):
                raise InputError(what, f"'{name}' contains non-finite values")
        fp = str(meta.get("scene_fingerprint", ""))
        if expected_fingerprint is not None and fp != expected_fingerprint:
            raise InputError(what, "photon map was traced for another scene (fingerprint mismatch: volume, "
                             "transfer function or lights differ)")
        emitted = int(meta.get("emitted", 0))
        if emitted <= 0:
            raise InputError(what, "photon map metadata has no positive 'emitted' count")
        return cls(arrays["position"], arrays["direction"], arrays["power"], arrays["phase"], phases, fp, emitted,
                   meta)
