"""The compressed PVRT transfer in memory, its precomputation end to end, and its file (format:
:mod:`photon_fields.models_spec.pvrt_transfer`).

:func:`precompute_transfer` runs Alg. 1's precomputation (``runtime/pvrt/precompute.py``, then CPCA,
``runtime/pvrt/cpca.py``). :func:`save_transfer` writes atomically and never replaces a file without ``force``;
:func:`load_transfer` validates everything (format, version, keys, array names/dtypes/shapes, finite values, the
scene it was made for) and reads with ``allow_pickle=False``; every refusal is one :class:`InputError` line.
"""

from __future__ import annotations

import json
import math
import re
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.fingerprint import mismatch_detail
from photon_fields.models_spec.pvrt_transfer import (
    PVRT_ARRAYS,
    PVRT_CPCA_KEYS,
    PVRT_FORMAT,
    PVRT_NPZ,
    PVRT_PARTS,
    PVRT_PHOTON_KEYS,
    PVRT_SCENE_PARTS,
    PVRT_SUFFIX,
    PVRT_VERSION,
)
from photon_fields.runtime.errors import InputError, check_keys, npz_errors_as_input
from photon_fields.runtime.io.atomic import atomic_path
from photon_fields.runtime.pvrt.basis import LightingBasis, check_basis, make_basis
from photon_fields.runtime.pvrt.constants import (
    DEFAULT_CLUSTERS,
    DEFAULT_PATHS_PER_BASIS,
    DEFAULT_PCA_BASES,
    EXITANCE_ORDERS,
    KERNEL_C,
    MAX_BOUNCES,
)
from photon_fields.runtime.pvrt.cpca import compress
from photon_fields.runtime.pvrt.precompute import precompute_raw
from photon_fields.runtime.pvrt.sh import sh_count
from photon_fields.runtime.scene.scene import Scene

_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the earliest zip timestamp (as train/export/bundle.py)
_SHA256 = re.compile(r"^[0-9a-f]{64}$")


@dataclass(eq=False)
class Transfer:
    """A CPCA-compressed transfer (arrays as in the file) and its manifest."""

    cluster: np.ndarray
    mass: np.ndarray
    weights: np.ndarray
    mean: np.ndarray
    basis_matrices: np.ndarray
    manifest: dict[str, Any]
    path: Path | None = None
    #: Where the precomputation's time went ({"trace", "cpca"} seconds); not in the file, whose bytes depend on
    #: the inputs and the seed only (None for a loaded transfer).
    seconds: dict[str, float] | None = None
    #: What the renderer derives from the transfer and the medium it was made for, once (e.g. the direct term's
    #: optical-depth volumes, ``runtime/pvrt/direct.py``); not in the file.
    cache: dict[Any, Any] = field(default_factory=dict, repr=False)

    @property
    def basis(self) -> LightingBasis:
        b = self.manifest["basis"]
        return make_basis(b["kind"], b["order"])

    @property
    def grid(self) -> tuple[int, int, int]:
        return tuple(self.manifest["grid"])  # type: ignore[return-value]

    @property
    def exitance_order(self) -> int:
        return int(self.manifest["exitance_order"])

    @property
    def g(self) -> float:
        return float(self.manifest["g"])

    def matrices(self) -> np.ndarray:
        """The decompressed transfer (V, m, parts, n) (for tests and tools; rendering never decompresses)."""
        from photon_fields.runtime.pvrt.cpca import CPCA

        c = CPCA(self.cluster, self.weights, self.mean, self.basis_matrices, 0.0).reconstruct()
        inv = np.where(self.mass > 0, 1.0 / np.maximum(self.mass, 1e-30), 0.0).astype(np.float32)
        return (c * inv[:, None]).reshape(len(self.cluster), self.basis.size, len(PVRT_PARTS),
                                          sh_count(self.exitance_order))

    def check_scene(self, scene: Scene, what: str | None = None) -> None:
        """Refuse a scene of another volume, transfer function or phase g, or another world box (one line)."""
        what = what or (str(self.path) if self.path else "transfer")
        parts = scene.fingerprint_parts()
        expected = {k: parts[k] for k in PVRT_SCENE_PARTS}
        recorded = self.manifest["scene_parts"]
        if expected != recorded:
            detail = mismatch_detail({**expected, "lights": ""}, {**recorded, "lights": ""})
            detail = detail.replace(" (lights match)", "").replace(" and lights match", " matches")
            raise InputError(what, f"transfer was precomputed for another scene ({self.manifest['scene_name']!r}): "
                             f"{detail}; precompute it for this one (pfn-train pvrt SCENE --out NAME.pvrt)")
        if abs(scene.g - self.g) > 1e-6:
            raise InputError(what, f"transfer was precomputed for phase g = {self.g:g}, the scene has g = "
                             f"{scene.g:g} (photons scattered with g); precompute it for this g")
        m = scene.medium()
        box = self.manifest["box"]
        if not (np.allclose(box["min"], m.bmin, atol=1e-9) and np.allclose(box["size"], m.bsize, atol=1e-9)):
            raise InputError(what, "transfer was precomputed for another world box (voxel spacing)")


def precompute_transfer(scene: Scene, *, basis: str = "dsf", order: int | None = None,
                        grid: int | None = None, exitance_order: int | None = None,
                        paths: int = DEFAULT_PATHS_PER_BASIS, clusters: int = DEFAULT_CLUSTERS,
                        bases: int = DEFAULT_PCA_BASES, seed: int = 0, progress: bool = True,
                        on_progress: Callable[[int, int], None] | None = None) -> Transfer:
    """Alg. 1's precomputation: basis-light photon tracing and splatting, then CPCA (module docstring).
    ``exitance_order`` None: the least the scene's g needs (:func:`photon_fields.runtime.pvrt.sh.
    auto_exitance_order`); ``grid`` None: the most cells the memory budget allows
    (:func:`photon_fields.runtime.pvrt.precompute.auto_grid`); ``order`` None (DSF): the finer DSF order where its
    transfer fits that budget at a useful grid (:func:`photon_fields.runtime.pvrt.precompute.auto_dsf_order`); all
    recorded in the manifest."""
    from photon_fields.runtime.pvrt.constants import DEFAULT_SH_ORDER, EXITANCE_TOLERANCE
    from photon_fields.runtime.pvrt.precompute import auto_dsf_order, reachable_counter
    from photon_fields.runtime.pvrt.sh import auto_exitance_order

    if exitance_order is None:
        exitance_order = auto_exitance_order(scene.g, EXITANCE_TOLERANCE)
    if order is None:
        order = (auto_dsf_order(reachable_counter(scene.medium()), exitance_order, grid) if basis == "dsf"
                 else DEFAULT_SH_ORDER)
    kind, order = check_basis(basis, order)
    lighting_basis = make_basis(kind, order)
    raw = precompute_raw(scene, lighting_basis, grid=grid, out_lmax=exitance_order, paths=paths, seed=seed,
                         progress=progress, on_progress=on_progress)
    t0 = time.perf_counter()
    groups = np.broadcast_to(np.arange(len(PVRT_PARTS))[None, :, None], raw.matrices.shape[1:])
    c = compress(raw.matrices, clusters, bases, seed=seed, groups=groups)  # the reachable cells' rows
    cluster = np.full(len(raw.reachable), -1, dtype=np.int32)
    cluster[raw.reachable] = c.cluster
    weights = np.zeros((len(raw.reachable), c.weights.shape[1]), dtype=np.float32)
    weights[raw.reachable] = c.weights
    cpca_s = time.perf_counter() - t0
    del raw.matrices
    parts = scene.fingerprint_parts()
    m = scene.medium()
    manifest = {"format": PVRT_FORMAT, "version": PVRT_VERSION, "scene_name": scene.name,
                "scene_parts": {k: parts[k] for k in PVRT_SCENE_PARTS}, "g": float(scene.g),
                "basis": {"kind": kind, "order": order}, "exitance_order": int(raw.out_lmax),
                "parts": list(PVRT_PARTS), "grid": [int(x) for x in raw.grid],
                "box": {"min": [float(x) for x in m.bmin], "size": [float(x) for x in m.bsize]},
                "cpca": {"clusters": int(c.mean.shape[0]), "bases": int(bases),
                         "relative_error": float(c.relative_error)},
                "photons": {"paths_per_basis": int(paths), "seed": int(seed), "max_bounces": MAX_BOUNCES,
                            "kernel_c": KERNEL_C}}
    return Transfer(cluster, raw.mass, weights, c.mean, c.basis, manifest,
                    seconds={"trace": float(raw.seconds), "cpca": float(cpca_s)})


def save_transfer(transfer: Transfer, path: str | Path, *, force: bool = False) -> Path:
    """Write ``transfer`` to ``path`` (NAME.pvrt) atomically; an existing file is replaced only with ``force``."""
    p = Path(path)
    if p.suffix != PVRT_SUFFIX:
        raise InputError(str(p), f"a transfer file must end in {PVRT_SUFFIX}")
    if p.exists() and not force:
        raise InputError(str(p), "exists; pass --force to replace it")
    meta = np.frombuffer(json.dumps(transfer.manifest, sort_keys=True).encode(), dtype=np.uint8)
    arrays = {"cluster": transfer.cluster, "mass": transfer.mass, "weights": transfer.weights,
              "mean": transfer.mean, "basis": transfer.basis_matrices, "manifest": meta}
    # np.savez stamps every entry with the current time; fixed timestamps keep the bytes reproducible.
    with atomic_path(p) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)
    return p


def load_transfer(path: str | Path, scene: Scene | None = None) -> Transfer:
    """Load and validate a transfer file; with ``scene`` also refuse one made for another volume, transfer
    function, g or box (:meth:`Transfer.check_scene`)."""
    p = Path(path)
    what = str(p)
    if not p.is_file():
        raise InputError(what, "transfer file not found (pfn-train pvrt SCENE --out NAME.pvrt makes one)")
    if not zipfile.is_zipfile(p):  # else np.load would talk of pickles about a text file
        raise InputError(what, "not a PVRT transfer (not an .npz zip; pfn-train pvrt SCENE --out NAME.pvrt makes one)")
    with npz_errors_as_input():
        manifest, arrays = PVRT_NPZ.read(p)
    _check_manifest(manifest, what)
    _check_arrays(arrays, manifest, what)
    t = Transfer(arrays["cluster"], arrays["mass"], arrays["weights"], arrays["mean"], arrays["basis"], manifest, p)
    if scene is not None:
        t.check_scene(scene)
    return t


def _check_manifest(meta: dict[str, Any], what: str) -> None:
    """The manifest's values (its format, version and keys are checked by :data:`PVRT_NPZ`)."""
    parts = meta["scene_parts"]
    if not isinstance(parts, dict):
        raise InputError(f"{what} manifest scene_parts", "must be an object")
    check_keys(parts, PVRT_SCENE_PARTS, f"{what} manifest scene_parts", required=PVRT_SCENE_PARTS)
    for k, v in parts.items():
        if not isinstance(v, str) or not _SHA256.match(v):
            raise InputError(f"{what} manifest scene_parts {k}", f"must be a sha256 hex string, got {v!r}")
    b = meta["basis"]
    if not isinstance(b, dict):
        raise InputError(f"{what} manifest basis", "must be an object {\"kind\", \"order\"}")
    check_keys(b, ("kind", "order"), f"{what} manifest basis", required=("kind", "order"))
    check_basis(b["kind"], b["order"], f"{what} manifest basis")
    lo, hi = EXITANCE_ORDERS
    eo = meta["exitance_order"]
    if isinstance(eo, bool) or not isinstance(eo, int) or not lo <= eo <= hi:
        raise InputError(f"{what} manifest exitance_order", f"must be an integer in [{lo}, {hi}], got {eo!r}")
    if meta["parts"] != list(PVRT_PARTS):
        raise InputError(f"{what} manifest parts", f"must be {list(PVRT_PARTS)}, got {meta['parts']!r}")
    grid = meta["grid"]
    if (not isinstance(grid, list) or len(grid) != 3
            or not all(isinstance(x, int) and not isinstance(x, bool) and x >= 2 for x in grid)):
        raise InputError(f"{what} manifest grid", f"must be three integers >= 2, got {grid!r}")
    g = meta["g"]
    if isinstance(g, bool) or not isinstance(g, (int, float)) or not -1 <= g <= 1:
        raise InputError(f"{what} manifest g", f"must be a number in [-1, 1], got {g!r}")
    box = meta["box"]
    if not isinstance(box, dict):
        raise InputError(f"{what} manifest box", "must be an object {\"min\", \"size\"}")
    check_keys(box, ("min", "size"), f"{what} manifest box", required=("min", "size"))
    for key, sub in (("cpca", PVRT_CPCA_KEYS), ("photons", PVRT_PHOTON_KEYS)):
        if not isinstance(meta[key], dict):
            raise InputError(f"{what} manifest {key}", "must be an object")
        check_keys(meta[key], sub, f"{what} manifest {key}", required=sub)
    if not isinstance(meta["scene_name"], str):
        raise InputError(f"{what} manifest scene_name", "must be a string")


def _check_arrays(arrays: dict[str, np.ndarray], meta: dict[str, Any], what: str) -> None:
    for name, (dtype, ndim) in PVRT_ARRAYS.items():
        a = arrays[name]
        if a.dtype != np.dtype(dtype) or a.ndim != ndim:
            raise InputError(what, f"'{name}' has dtype {a.dtype} and {a.ndim} dimensions, expected {dtype} "
                             f"and {ndim}")
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise InputError(what, f"'{name}' holds non-finite values")
    b = meta["basis"]
    m = make_basis(b["kind"], b["order"]).size
    v = int(np.prod(meta["grid"]))
    k, n = meta["cpca"]["clusters"], meta["cpca"]["bases"]
    d = m * len(PVRT_PARTS) * sh_count(meta["exitance_order"])
    expected = {"cluster": (v,), "mass": (v,), "weights": (v, n), "mean": (k, d), "basis": (k, n, d)}
    for name, shape in expected.items():
        if arrays[name].shape != shape:
            raise InputError(what, f"'{name}' has shape {arrays[name].shape}, expected {shape} for the manifest's "
                             "grid, basis, exitance order and CPCA sizes")
    c = arrays["cluster"]
    if c.size and (c.min() < -1 or c.max() >= k):
        raise InputError(what, f"'cluster' holds indices outside [-1, {k - 1}]")
    if not math.isfinite(float(meta["cpca"]["relative_error"])):
        raise InputError(f"{what} manifest cpca", "relative_error must be finite")
