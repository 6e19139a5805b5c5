"""The renderers ``pfn-render`` offers, in one table: adding a renderer is its module plus one entry here.

Every renderer is called the same way::

    render(scene, *, spp, seed, batch_size, progress, **inputs, **options) -> RenderResult

``inputs`` are what the command line loads for it (``"map"``: ``pmap=`` a photon map and ``force=``;
``"bundle"``: ``estimator=`` a photon field's estimator; ``"transfer"``: ``transfer=`` a PVRT transfer),
``options`` its own settings, each declared as an
:class:`Option` that the command line turns into a flag, validates before any work and passes on by keyword.
The render functions are imported when a renderer is first used, so building the command line stays cheap.
"""

from __future__ import annotations

import argparse
import importlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from photon_fields.runtime.errors import InputError, check_choice

#: What a renderer can ask the command line to load: the flag that names the file, and what it is.
INPUTS = {"map": ("--map", "a photon map (pfn-train trace SCENE --out map.npz)"),
          "bundle": ("--bundle", "a bundle (pfn-train all SCENE --out run/ writes run/field.pfn)"),
          "transfer": ("--transfer", "a PVRT transfer (pfn-train pvrt SCENE --out NAME.pvrt)")}


def int_in(lo: int, hi: int) -> Callable[[str, Any], int]:
    """A check for an integer option in ``[lo, hi]``."""

    def check(flag: str, value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise InputError(flag, f"must be an integer in [{lo}, {hi}], got {value}")
        return value

    return check


def float_in(lo: float, hi: float, unit: str, *, open_low: bool = False) -> Callable[[str, Any], float]:
    """A check for a finite float option in ``[lo, hi]`` (``(lo, hi]`` with ``open_low``), in ``unit``."""

    def check(flag: str, value: Any) -> float:
        v = float(value)
        low_ok = v > lo if open_low else v >= lo
        if not (math.isfinite(v) and low_ok and v <= hi):
            raise InputError(flag, f"must be in {'(' if open_low else '['}{lo:g}, {hi:g}] {unit}, got {value}")
        return v

    return check


def one_of(choices: tuple[str, ...]) -> Callable[[str, Any], str]:
    """A check for a string option that must be one of ``choices``."""

    return lambda flag, value: check_choice(flag, value, choices)


def optional(check: Callable[[str, Any], Any]) -> Callable[[str, Any], Any]:
    """``check`` for an option whose default None means "the render function decides"."""
    return lambda flag, value: None if value is None else check(flag, value)


def negate(flag: str, value: Any) -> bool:
    """For a ``--no-X`` switch that sets keyword ``X``."""
    return not value


@dataclass(frozen=True)
class Option:
    """A renderer's own setting, as the command line offers it."""

    flag: str
    """Command-line flag, e.g. ``--max-depth``."""
    keyword: str
    """The render function's keyword argument it sets."""
    help: str
    """One line for ``--help``."""
    type: Callable[[str], Any] | None = None
    """argparse type of the value; None makes the flag a switch (``store_true``)."""
    default: Any = None
    """Default value on the command line (the render function's own default, so both agree)."""
    check: Callable[[str, Any], Any] | None = None
    """``check(flag, value) -> keyword value``: refuses a bad value in one line naming the flag."""

    def value(self, given: Any) -> Any:
        """The keyword value for the command-line value ``given`` (checked)."""
        return self.check(self.flag, given) if self.check is not None else given


@dataclass(frozen=True)
class Renderer:
    """One entry of :data:`RENDERERS`."""

    name: str
    """``--method`` value."""
    summary: str
    """What it computes, for ``--help``."""
    function: str
    """``module:function`` of the render function (imported on first use)."""
    options: tuple[Option, ...] = ()
    """Its own settings."""
    input: str | None = None
    """What the command line loads for it: a key of :data:`INPUTS`, or None."""
    progressive: bool = True
    """Whether its frames are estimates that average to the image (another seed, another frame). False for a
    renderer whose frame is the same for every sample index of one seed (a fixed jittered march): a viewer then
    renders one frame per view and neither accumulates nor denoises it."""
    noisy: bool = True
    """Whether its frames carry Monte Carlo noise, which a viewer's denoiser removes. False for the ray marcher: its
    frames differ only by where each pixel's jitter puts the samples along its ray, which accumulating a few frames
    averages, and a denoiser would only blur the detail it keeps."""

    def render_function(self) -> Callable[..., Any]:
        """The render function itself."""
        module, name = self.function.split(":")
        return getattr(importlib.import_module(module), name)


#: The coarsest volume level the ray marcher takes (runtime.scene.levels.MAX_LEVEL; spelt out here so that building
#: the command line does not import numpy, and tested to agree).
MAX_LEVEL = 5

#: The first-interaction renderers' camera estimator (runtime.wavefront.first_interaction.CAMERA_ESTIMATORS and
#: camera_choice.AUTO; spelt out here so that building the command line does not import numba kernels).
CAMERA_ESTIMATOR_NAMES = ("auto", "forced", "marched", "delta")
CAMERA_OPTION = Option("--camera-estimator", "camera", "camera estimator: auto (forced or marched, whichever has less "
                       "noise per unit of work on this scene, from a probe of a band of rows), forced (a collision "
                       "resampled from the whole ray, weighted by its collision probability; less noise in thin "
                       "media), marched (the preview's cached light summed along the whole ray and corrected at three "
                       "points: least noise per millisecond in sparse media, 3-4x the time per sample) or delta (delta "
                       "tracking, the path tracer's first bounce)", str, "auto", one_of(CAMERA_ESTIMATOR_NAMES))


def checked_camera_estimator(name: str | None) -> str:
    """``name`` if it is a camera estimator (None: the default), else a one-line error naming the flag."""
    return CAMERA_OPTION.default if name is None else CAMERA_OPTION.check(CAMERA_OPTION.flag, name)


#: The first-interaction renderers' NEE over several lights (runtime.wavefront.first_interaction.LIGHT_SAMPLINGS).
LIGHT_OPTION = Option("--light-sampling", "light_sampling", "next-event estimation with several lights: one (one "
                      "shadow ray per sample, to a light drawn by its unshadowed contribution) or all (a shadow ray to "
                      "every light: less noise, more time)", str, "one", one_of(("one", "all")))

#: Samples of a render (or of a viewer's resting view) from which the first-interaction renderers take the final
#: gather (runtime.wavefront.final_gather): by then the image's noise is below the estimator's bias, which the gather
#: reduces (measurements: bench/README.md, ``bench_final_gather.py``).
DEFAULT_GATHER_AFTER = 128

#: The ray marcher's early ray termination: a camera ray stops once its transmittance is below this. 0.03 rather than
#: 0.01: fewer samples per ray and fewer light-volume cells filled behind what a new jitter reaches, for a change of
#: the image far below the preview's own error (bench/README.md, ``bench_ray_marcher.py``, "Early ray termination").
DEFAULT_MIN_TRANSMITTANCE = 0.03


def spp_or_never(text: str) -> int | None:
    """``--final-gather-after``'s argparse type: a sample count, or ``never`` (None)."""
    if text == "never":
        return None
    if not text.isdigit() or int(text) > 1 << 16:
        raise argparse.ArgumentTypeError(f"expected a sample count in [0, {1 << 16}] or never, got {text!r}")
    return int(text)


#: A check for ``final_gather_after``: a sample count in [0, 2^16], or None (never).
spp_or_none = optional(int_in(0, 1 << 16))


#: One real bounce before the first-interaction renderers' L_i estimate (runtime.wavefront.final_gather).
GATHER_OPTION = Option("--final-gather-after", "final_gather_after", "a pixel's samples from this index on take "
                       "one real bounce (phase sampling, tracking, NEE) before the L_i estimate: less of its bias, "
                       "more noise, about 1.5x the time per sample; 0: every sample, never: none", spp_or_never,
                       DEFAULT_GATHER_AFTER, spp_or_none)

#: The ray marcher's own settings (shared by ``raymarch`` and ``raymarch-field``).
MARCH_OPTIONS = (
    Option("--step", "step", "camera-ray step length in voxels", float, 1.0, float_in(0.01, 100, "voxels")),
    Option("--max-step", "max_step", "longest camera-ray segment in voxels (default: 4 steps): where "
           "sigma_t is smooth and thin a segment spans several steps (--step or less: fixed steps)", float,
           None, optional(float_in(0.01, 100, "voxels"))),
    Option("--shadows", "shadows", "volume (each light's transmittance cached in a light volume: the "
           "preview) or march (a shadow ray per sample and light: the paper's baseline)", str, "volume",
           one_of(("volume", "march"))),
    Option("--shadow-step", "shadow_step", "shadow-ray step length in voxels (default: 0.5 for "
           "--shadows volume, 1 for march; below 1 on media with sharp, dense boundaries: the 1-voxel sum "
           "reads bright there)", float, None, optional(float_in(0.01, 100, "voxels"))),
    Option("--light-grid-scale", "light_grid_scale", "--shadows volume: light-volume cells per voxel "
           "along each axis (default: 1, fewer for volumes over ~320^3 voxels: at most 128 MiB a light)",
           float, None, optional(float_in(0.25, 4, "cells per voxel"))),
    Option("--min-transmittance", "min_transmittance", "early ray termination: a camera ray stops once "
           "its transmittance is below this", float, DEFAULT_MIN_TRANSMITTANCE, float_in(0, 0.5, "(transmittance)")),
    Option("--level", "level", "march a coarser level of the volume: blocks of 2^LEVEL voxels a side "
           "averaged in the same box (a quick look at a large volume; walls one or two voxels thick read "
           "thicker)", int, 0, int_in(0, MAX_LEVEL)),
)

RENDERERS: dict[str, Renderer] = {r.name: r for r in (
    Renderer("pt", "volumetric path tracer (reference)",
             "photon_fields.runtime.renderers.path_tracer:render_path_traced",
             (Option("--max-depth", "max_depth", "max scattering vertices per path, with or without --no-nee "
                     "(1: single scattering)", int, 16, int_in(1, 1 << 16)),
              Option("--no-nee", "nee", "pure phase sampling (no next-event estimation; reaches the environment "
                     "light only)", check=negate))),
    Renderer("raymarch", "single-scattering ray marcher with global shadows (a noise-free preview without L_i)",
             "photon_fields.runtime.renderers.ray_marcher:render_ray_marched", MARCH_OPTIONS, noisy=False),
    Renderer("raymarch-field", "the ray marcher's single scattering plus the photon field's L_i at one point per "
             "ray drawn along the march: a quick look with multiple scattering, little noise, a few per cent of "
             "the preview's bias in L_d (needs --bundle)",
             "photon_fields.runtime.renderers.ray_marcher:render_ray_marched", MARCH_OPTIONS, input="bundle"),
    Renderer("photonmap", "first interactions + NEE + the photon-map estimate of L_i (needs --map)",
             "photon_fields.runtime.renderers.photon_mapped:render_photon_mapped",
             (Option("--k", "k", "photons per estimate (K)", int, 1024, int_in(2, 1 << 16)),
              Option("--radius", "radius", "max search radius, in units of the volume box's longest side", float,
                     0.05, float_in(0, 2, "box units", open_low=True)), CAMERA_OPTION, LIGHT_OPTION, GATHER_OPTION),
             input="map"),
    Renderer("field", "the neural renderer (Alg. 2): first interactions + NEE + the photon field's L_i "
             "(needs --bundle)", "photon_fields.runtime.renderers.neural:render_neural",
             (CAMERA_OPTION, LIGHT_OPTION, GATHER_OPTION),
             input="bundle"),
    # Defaults spelt out as in runtime.pvrt.constants / lighting (not imported: building the CLI stays cheap).
    Renderer("pvrt", "PVRT relighting (Zhang et al. 2013) from a precomputed transfer: distant lights only, "
             "multiple scattering from the transfer, directional lights' direct term by NEE (needs --transfer)",
             "photon_fields.runtime.renderers.pvrt:render_pvrt",
             (Option("--direct", "direct", "direct term of directional lights: nee (a light volume of their "
                     "transmittance, sharp shadows) or transfer (from the lighting basis, blurred)", str, "nee",
                     one_of(("nee", "transfer"))),
              Option("--light-grid", "light_grid", "pvrt --direct nee: light-volume cells along the box's longest "
                     "side", int, 128, int_in(4, 512))),
             input="transfer", progressive=False, noisy=False),
)}
