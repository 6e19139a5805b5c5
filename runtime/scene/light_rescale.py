"""An exact shortcut for light edits: a field (or map) made for some lights answers for the same lights rescaled.

Radiance is linear in the emitted flux: every photon path, and every path a path tracer samples, carries a factor
of its light's RGB flux (power x colour) and nothing else of it, while where a light is and how it emits (a point,
a direction, an environment image and its rotation) decides which paths there are. So when an edit keeps every
light's kind and geometry and multiplies every light's RGB flux by one common factor s (per channel), L_i of the
edited scene is s times L_i of the trained one, exactly: with a single light, any change of its power or colour;
with several, the same change of all. Lights that change by different factors are a rescale of each light's part
apart (:func:`per_light_rescale`), which a field or map can follow only if it keeps the lights' parts apart: a field
with one output per light (``FieldConfig.light_channels``), a map that records each photon's light.

:func:`flux_rescale` takes the lights as their fingerprint dicts (:func:`photon_fields.runtime.scene.lights.
light_identity`, or the ``to_dict`` a bundle's manifest records with the scene it was trained for; an environment
map's ``path`` is ignored, its pixels' ``sha256`` is not), so that a bundle can be checked against a scene without
either being rebuilt.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from photon_fields.models_spec.fingerprint import differing_parts

#: Keys of a light's dict that carry its flux; every other key (type, position, direction, rotation, the image's
#: hash) is geometry and must be equal. ``path`` only names an image file (its ``sha256`` stands for the pixels).
FLUX_KEYS = ("color", "power")
IGNORED_KEYS = ("path",)
#: Relative agreement the per-light factors of one channel need to count as one factor.
RTOL = 1e-9


def _geometry(light: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in light.items() if k not in FLUX_KEYS and k not in IGNORED_KEYS}


def _flux(light: Mapping[str, Any]) -> np.ndarray:
    return np.asarray(light["color"], dtype=np.float64) * float(light["power"])


def _fluxes(trained: Sequence[Mapping[str, Any]],
            edited: Sequence[Mapping[str, Any]]) -> tuple[np.ndarray, np.ndarray] | None:
    """The lights' RGB fluxes before and after (L, 3 each) when the edit keeps their number, kinds and geometry and
    both are finite; else None."""
    if len(trained) != len(edited) or not trained:
        return None
    try:
        if any(_geometry(a) != _geometry(b) for a, b in zip(trained, edited, strict=True)):
            return None
        before = np.stack([_flux(a) for a in trained])
        after = np.stack([_flux(b) for b in edited])
    except (KeyError, TypeError, ValueError):
        return None
    if before.shape[1] != 3 or after.shape != before.shape or not (np.all(np.isfinite(before))
                                                                   and np.all(np.isfinite(after))):
        return None
    return before, after


def _per_light(before: np.ndarray, after: np.ndarray) -> np.ndarray | None:
    lit = before > 0.0
    if np.any(after[~lit] != 0.0):
        return None  # light where the trained light had none in this channel
    return np.where(lit, after / np.where(lit, before, 1.0), 1.0)


def per_light_rescale(trained: Sequence[Mapping[str, Any]],
                      edited: Sequence[Mapping[str, Any]]) -> np.ndarray | None:
    """The RGB factor of each light (L, 3): light l's part of L_i in the edited scene is ``s[l]`` times its part in
    the trained one. None when the edit is not a rescale of each light's flux: another number of lights, a light of
    another kind or geometry, or a light lit now in a channel where it was dark (its part holds nothing to scale);
    a channel dark before and after has factor 1."""
    fluxes = _fluxes(trained, edited)
    return None if fluxes is None else _per_light(*fluxes)


def flux_rescale(trained: Sequence[Mapping[str, Any]], edited: Sequence[Mapping[str, Any]]) -> np.ndarray | None:
    """The RGB factor s (3,) with L_i(edited) = s * L_i(trained) (module docstring), or None when the edit is not a
    common rescale of the lights' flux: :func:`per_light_rescale` is None, or the lights lit in a channel are
    scaled by different factors in it."""
    fluxes = _fluxes(trained, edited)
    per_light = None if fluxes is None else _per_light(*fluxes)
    if per_light is None:
        return None
    lit = fluxes[0] > 0.0
    scale = np.ones(3)
    for c in range(3):
        if not np.any(lit[:, c]):
            continue  # dark before and after: L_i is 0 in this channel either way
        ratios = per_light[lit[:, c], c]
        if ratios.max() - ratios.min() > RTOL * max(ratios.max(), 1e-300):
            return None
        scale[c] = float(ratios.mean())
    return scale


def lights_rescale(trained: Sequence[Mapping[str, Any]], edited: Sequence[Mapping[str, Any]],
                   apart: int = 1) -> np.ndarray | None:
    """How an L_i made for the ``trained`` lights follows the ``edited`` ones, for a field or map that keeps
    ``apart`` lights apart (a field's ``light_channels``, a map's ``light_count``; 1: their sum only): one factor
    per light (:func:`per_light_rescale`, (L, 3)) when it keeps every trained light apart, else the common factor
    (:func:`flux_rescale`, (3,)); None when it cannot follow the edit."""
    if apart > 1 and apart == len(trained):
        return per_light_rescale(trained, edited)
    return flux_rescale(trained, edited)


def scene_rescale(trained_parts: Mapping[str, str] | None, trained_lights: Any, parts: Mapping[str, str],
                  lights: Sequence[Mapping[str, Any]], apart: int = 1) -> np.ndarray | None:
    """:func:`lights_rescale` from a trained scene to another when the lights are all that differs between them
    (their per-part fingerprints: the same volume and transfer function), else None; ``trained_lights`` as recorded
    (a bundle's manifest, a map's metadata, a run folder), None or anything not a list when not recorded."""
    if not isinstance(trained_lights, list) or differing_parts(parts, trained_parts) != ["lights"]:
        return None
    return lights_rescale(trained_lights, lights, apart)


def format_scale(scale: np.ndarray) -> str:
    """``(1.5, 1.5, 1.5)``: an RGB factor for a message; one per light (L, 3): ``light 1 (1, 1, 1), light 2 (2, 2,
    2)``, or the common one when all lights have it."""
    s = np.asarray(scale, dtype=np.float64)
    if s.ndim == 2:
        if np.all(s == s[:1]):
            return format_scale(s[0])
        return ", ".join(f"light {i + 1} {format_scale(row)}" for i, row in enumerate(s))
    return "(" + ", ".join(f"{v:.4g}" for v in s) + ")"


def rescale_note(scale: np.ndarray, what: str = "field") -> str:
    """One line for the user: the lights differ only by flux factors (common, or per light for a ``what`` that keeps
    the lights apart), which the ``what``'s L_i follows."""
    return (f"the lights differ from the {what}'s only in power or colour: its L_i is rescaled by "
            f"{format_scale(scale)} per RGB channel (exact: radiance is linear in a light's flux)")


__all__ = ["flux_rescale", "per_light_rescale", "lights_rescale", "scene_rescale", "format_scale", "rescale_note",
           "FLUX_KEYS"]
