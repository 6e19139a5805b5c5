"""PVRT transfer file format (written by ``pfn-train pvrt`` / ``runtime.pvrt.transfer.save_transfer``, read by
``runtime.pvrt.transfer.load_transfer``).

A transfer is one ``NAME.pvrt`` file: an uncompressed ``.npz`` zip (read with ``allow_pickle=False``) of exactly
these arrays (V cells of the transfer grid, K clusters, N PCA bases, D = m * len(parts) * (exitance_order + 1)^2):

==========  ===============  ====================================================================================
array       dtype/shape      meaning
==========  ===============  ====================================================================================
cluster     int32 (V,)       CPCA cluster of each cell (Eq. 16), -1 for empty cells; cells in C order over grid
mass        float32 (V,)     D_v, the kernel-weighted extinction of each cell: transfer matrix = CPCA matrix / D_v
weights     float32 (V, N)   each cell's PCA weights w_i
mean        float32 (K, D)   each cluster's mean matrix T_mean^k, flattened as [basis light, part, SH coefficient]
basis       float32 (K,N,D)  each cluster's PCA basis matrices T_i^k
manifest    uint8 (bytes,)   UTF-8 JSON, below
==========  ===============  ====================================================================================

Manifest keys (:data:`PVRT_MANIFEST_KEYS`, all required; a reader refuses any other, naming it): ``format``
(= PVRT_FORMAT), ``version`` (= PVRT_VERSION), ``scene_name``, ``scene_parts`` (the per-part fingerprints of the
volume and the transfer function, :func:`photon_fields.models_spec.fingerprint.fingerprint_parts` without the
lights: a transfer is made to be relit), ``g`` (the phase coefficient every photon scattered with), ``basis``
(``{"kind": "dsf" | "sh", "order": int}``), ``exitance_order`` (SH l_max of the per-cell radiance), ``parts``
(= PVRT_PARTS), ``grid`` ([gx, gy, gz]), ``box`` (``{"min": [3], "size": [3]}``, the world box), ``cpca``
(``{"clusters": K, "bases": N, "relative_error": float}``), ``photons`` (``{"paths_per_basis", "seed",
"max_bounces", "kernel_c"}``).

The file is a pure function of the scene's volume, transfer function and g and of the settings and seed: the zip
entries carry a fixed timestamp and the manifest no timings (``pfn-train pvrt`` prints them), so the same seed
writes the same bytes.
"""

from __future__ import annotations

from photon_fields.models_spec.npz_manifest import NpzManifestFormat

PVRT_FORMAT = "photon-fields/pvrt-transfer"
PVRT_VERSION = 1
PVRT_SUFFIX = ".pvrt"
PVRT_PARTS: tuple[str, ...] = ("direct", "ms_r", "ms_g", "ms_b")
PVRT_ARRAYS: dict[str, tuple[str, int]] = {"cluster": ("int32", 1), "mass": ("float32", 1), "weights": ("float32", 2),
                                           "mean": ("float32", 2), "basis": ("float32", 3)}
PVRT_MANIFEST_KEYS: tuple[str, ...] = ("format", "version", "scene_name", "scene_parts", "g", "basis",
                                       "exitance_order", "parts", "grid", "box", "cpca", "photons")
PVRT_SCENE_PARTS: tuple[str, ...] = ("volume", "transfer_function")
PVRT_CPCA_KEYS: tuple[str, ...] = ("clusters", "bases", "relative_error")
PVRT_PHOTON_KEYS: tuple[str, ...] = ("paths_per_basis", "seed", "max_bounces", "kernel_c")
#: The file layout above, and its reader (:mod:`photon_fields.models_spec.npz_manifest`).
PVRT_NPZ = NpzManifestFormat(kind="PVRT transfer", format=PVRT_FORMAT, version=PVRT_VERSION, entry="manifest",
                             label="manifest", keys=PVRT_MANIFEST_KEYS, required=PVRT_MANIFEST_KEYS,
                             arrays=tuple(PVRT_ARRAYS), remedy="precompute it again")
