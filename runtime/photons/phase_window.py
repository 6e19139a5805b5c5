"""A kernel in g: photon-map estimates at any phase coefficient from a map traced in many narrow phase bins.

A photon map answers only the g it was traced with (Eq. 5 is phase-selective): each phase bin of the map
is a complete map of the light whose every scattering used that bin's g. To answer a g between the bins, and
to train a field on every g rather than on a few, the map is traced in many narrow bins
(:data:`photon_fields.models_spec.photon_map.PHASE_BINS`) and a query at g uses the union of the bins near
it, each bin's photons weighted by a triangular kernel of half-width h (:data:`PHASE_WINDOW`):

    w_b(g) = max(0, 1 - |g_b - g| / h) / sum_b' max(0, 1 - |g_b' - g| / h)

Since every bin is a complete map and the weights sum to 1, the weighted union is a complete map too: the light
of a medium whose earlier scatterings used a g drawn from the kernel around g. The last scattering, the
sharpest dependence on g (L_i is strongly convex in g near |g| = 0.75), is exact: the estimate evaluates the
phase function at the query's own g for every photon. Only the earlier bounces are averaged over the kernel.

The estimate reads one search structure for every g (:meth:`photon_fields.runtime.photons.estimate.
PhotonMapEstimator.binned_index`): the map's photons sorted by grid cell and, inside a cell, by bin, so the search
at g scans, in each cell, the run of g's kernel bins, and weighs each photon by its bin's kernel weight. That is
the estimate over the weighted union of the bins above with the kernel centred at g itself, and it holds each
photon once.

Why a window and not one narrow bin: the estimate's bias at dense surfaces grows with the KNN ball, and the
ball grows as photons per map shrink; a window of ~7 bins holds about as many photons as one phase of today's
five-phase map, so the ball stays as small. Why triangular: for a window inside the bins' range the kernel is
symmetric about g, so the average of the earlier bounces is exact to first order in h (error
~ h^2 / 12 * d2L/dg2); near the ends of the range the window is cut and that no longer holds, so
:func:`window_range` is the range of g whose window is whole.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from photon_fields.models_spec.photon_map import PHASE_WINDOW
from photon_fields.runtime.errors import InputError

__all__ = ["PHASE_WINDOW", "bin_spacing", "check_window", "answerable", "map_window", "window_range", "window_weights"]
#: A window must hold at least this many bins to be a kernel rather than a single phase.
MIN_BINS_PER_WINDOW = 3
_EPS = 1e-9


def window_weights(phases: Sequence[float], g: float, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(bin indices, weights summing to 1) of the triangular kernel of half-width ``h`` centred at ``g`` over the
    map's phase bins ``phases``. InputError when no bin lies strictly inside the window."""
    gs = np.asarray(phases, dtype=np.float64)
    w = np.maximum(0.0, 1.0 - np.abs(gs - float(g)) / float(h))
    idx = np.flatnonzero(w > _EPS)
    if idx.size == 0:
        raise InputError("g", f"g = {g} has no phase bin within {h} (the map's bins span "
                         f"[{gs.min():g}, {gs.max():g}])")
    return idx, w[idx] / w[idx].sum()


def bin_spacing(phases: Sequence[float]) -> float:
    """The largest gap between adjacent phase bins (inf for a single bin)."""
    gs = np.sort(np.asarray(phases, dtype=np.float64))
    return float(np.diff(gs).max()) if gs.size > 1 else float("inf")


def check_window(phases: Sequence[float], h: float) -> None:
    """Refuse a window that is not a kernel over these bins: h out of (0, 1], or bins so sparse that a window
    holds fewer than :data:`MIN_BINS_PER_WINDOW` of them (then it is a phase, and g between bins is wrong)."""
    if not (isinstance(h, int | float) and 0.0 < h <= 1.0):
        raise InputError("g window", f"must be a half-width in (0, 1], got {h!r}")
    spacing = bin_spacing(phases)
    if (2.0 * h) / spacing + _EPS < MIN_BINS_PER_WINDOW - 1:
        raise InputError("photon map", f"its phase bins are {spacing:g} apart, too sparse for a g window of "
                         f"+-{h:g} (at most {2.0 * h / (MIN_BINS_PER_WINDOW - 1):g} apart); trace it with "
                         f"narrow bins (pfn-train trace's default --phases)")


def map_window(phases: Sequence[float], g_window: float | str | None = "auto") -> float | None:
    """The kernel half-width a photon map is read with: ``"auto"`` gives PHASE_WINDOW for a map traced in bins
    dense enough for it (then every g between its bins is answered) and None (g must be a traced phase) for
    others; a number or None is taken as given."""
    if g_window != "auto":
        return None if g_window is None else float(g_window)
    try:
        check_window(phases, PHASE_WINDOW)
    except InputError:
        return None
    return PHASE_WINDOW


def answerable(phases: Sequence[float], g: float, g_window: float | None, what: str = "g") -> None:
    """InputError (naming ``what``) unless a map of these phases, read with ``g_window``, answers g."""
    if g_window is None:
        if not any(abs(float(p) - g) < 1e-6 for p in phases):
            raise InputError(what, f"g = {g} is not in the photon map's phase set {list(phases)}")
        return
    window_weights(phases, g, g_window)


def window_range(phases: Sequence[float], h: float) -> tuple[float, float]:
    """[lo, hi]: the g whose window lies whole inside the bins' range (a symmetric kernel). Empty ranges refused."""
    gs = np.asarray(phases, dtype=np.float64)
    lo, hi = float(gs.min()) + h, float(gs.max()) - h
    if hi < lo - _EPS:
        raise InputError("photon map", f"its phase bins span [{gs.min():g}, {gs.max():g}], narrower than one "
                         f"g window of +-{h:g}")
    return lo, max(lo, hi)
