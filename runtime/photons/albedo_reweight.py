"""An edit of the albedo alone: the earlier photon map's paths, reweighted exactly, instead of a retrace.

Photon tracing (paper Alg. 1, ``train/photons/tracing.py``; the transport of
:func:`photon_fields.runtime.photons.photon_path.trace_path`) flies a photon by delta tracking, which sees sigma_t
only, scatters it with the phase function, and at each collision x_j plays Russian roulette with survival
q_j = max_c a_c(x_j), the survivor's power multiplied by a(x_j) / q_j. A record at collision k of a path carries

    Phi_k = Phi_0 prod_{j<k} a(x_j) / q_j.

An edit that changes the albedo a -> a' and nothing else (the same extinction everywhere, volume and lights) leaves
every flight, direction and roulette draw of a path as likely as before: the old roulette is still a valid one for
a' (its survival q_j > 0 wherever a' > 0), so

    Phi'_k = Phi_k prod_{j<k} a'(x_j) / a(x_j)

is an unbiased record of the edited scene: the same paths, each record reweighted. The map holds, per record, the
collision's number along its path (``bounce``; a path's records are consecutive, the first at 2; a null record of a
map traced with a record floor, :mod:`photon_fields.runtime.photons.photon_path`, has the number of the collision it
precedes, and so its earlier collisions) and the scalar at
the path's previous collision (``prev_scalar``; the first collision is not stored, so that is where its scalar is
kept), which is all the product needs: a' and a are the transfer functions' albedo of that scalar. Where an old
albedo channel is 0 and the new one is not, the paths hold no information about the new light (the roulette killed
them there): :func:`reweight_albedo` says so (None) and the caller retraces.

Thinning. ``keep`` < 1 keeps each path (all its records) with probability ``keep`` and divides the powers by it: an
unbiased map of about ``keep`` times the records, what a retrace with fewer photons gives (``pfn-train update``
trains on 1M records; the earlier run's map may hold 5M).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.transport.medium import Medium, _albedo_of


def albedo_only(before: Medium, after: Medium) -> bool:
    """Whether ``after`` is ``before`` with another albedo and nothing else: the same box, scalar volume and
    extinction of every scalar (a transfer function's colours edited, not its opacity or density)."""
    return (before.categorical == after.categorical and np.array_equal(before.bmin, after.bmin)
            and np.array_equal(before.bsize, after.bsize) and np.array_equal(before.ext_lut, after.ext_lut)
            and (before.density is after.density or np.array_equal(before.density, after.density)))


@njit(cache=True)
def _path_factors(bounce: np.ndarray, prev: np.ndarray, old_lut: np.ndarray, new_lut: np.ndarray,
                  categorical: bool, out: np.ndarray) -> bool:
    """out[i] = prod over record i's earlier collisions of a'/a (RGB); False where an old channel is 0 and the new
    one is not (no reweighting can recover that light)."""
    f0 = f1 = f2 = 1.0
    for i in range(bounce.shape[0]):
        if bounce[i] <= 2:  # a new path, or a record before a path's second real collision: one factor
            f0 = f1 = f2 = 1.0
        elif bounce[i] == bounce[i - 1]:  # a null record and the collision it precedes: the same earlier ones
            out[i, 0], out[i, 1], out[i, 2] = f0, f1, f2
            continue
        a0, a1, a2 = _albedo_of(old_lut, categorical, prev[i])
        b0, b1, b2 = _albedo_of(new_lut, categorical, prev[i])
        if (a0 <= 0.0 < b0) or (a1 <= 0.0 < b1) or (a2 <= 0.0 < b2):
            return False
        f0 = f0 * (b0 / a0) if a0 > 0.0 else f0  # a channel dark before and after: its power is 0 already
        f1 = f1 * (b1 / a1) if a1 > 0.0 else f1
        f2 = f2 * (b2 / a2) if a2 > 0.0 else f2
        out[i, 0], out[i, 1], out[i, 2] = f0, f1, f2
    return True


def reweight_albedo(pmap: PhotonMap, before: Medium, after: Medium, scene: object, *, keep: float = 1.0,
                    seed: int = 0) -> PhotonMap | None:
    """``pmap`` (traced for ``before``) as a map of ``scene`` (whose medium is ``after``, :func:`albedo_only`):
    each record's power times the product of a'/a over its path's earlier collisions (module docstring), the paths
    thinned to ``keep`` of them (seeded). None when the map lacks its path records (traced before they were kept) or
    the new albedo lights a channel the old one left dark."""
    if pmap.bounce is None or pmap.prev_scalar is None or not albedo_only(before, after):
        return None
    if not 0.0 < keep <= 1.0:
        raise ValueError(f"keep must be in (0, 1], got {keep!r}")
    factors = np.empty((len(pmap), 3))
    if not _path_factors(pmap.bounce, pmap.prev_scalar.astype(np.float64), before.albedo_lut, after.albedo_lut,
                         bool(before.categorical), factors):
        return None
    power = (pmap.power * factors).astype(np.float32)
    sel = slice(None)
    if keep < 1.0:
        path = np.cumsum(pmap.bounce <= 2) - 1  # each record's path
        kept = np.random.default_rng([int(seed) & (2**64 - 1), 7]).random(int(path[-1]) + 1 if len(path) else 0)
        sel = (kept < keep)[path]
        power = (power / np.float32(keep)).astype(np.float32)
    meta = {**pmap.meta, "scene_parts": scene.fingerprint_parts(), "lights": scene.light_identities()}
    return PhotonMap(pmap.position[sel], pmap.direction[sel], power[sel], pmap.phase[sel], pmap.phases,
                     scene.fingerprint(), pmap.emitted, meta, None,
                     **{name: a[sel] for name, a in pmap.optional_arrays().items()})


__all__ = ["albedo_only", "reweight_albedo"]
