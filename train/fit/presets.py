"""Training presets: a field architecture and the settings to train it, in one table (:data:`PRESETS`).

- ``paper``: Sec. 3.4/3.5 as published (both encodings 16 levels x 8 features, 2x scale, 2^19 tables, 4 hidden
  layers of 64, batch 2^16, 3000 steps, the Table-1 KNN schedule, samples uniform in the box). Hours on 2
  CPU cores; kept to reproduce the paper.
- ``cpu``: the default, chosen for useful targets per second on 2 cores: samples in the medium's support (the renderer
  never queries empty space), half of them where cameras around the volume see it, with the direction they see it from
  (``sampling="visible"``: the renderer's queries), the final radius from the start, small batches and many steps, a
  richer network than its cost suggests because targets, not the network, dominate a step; any g of [-0.8, 0.8]
  (past the paper's [-0.75, 0.75]: a field is worst at the ends of its g range) trained from a kernel in g over a map
  traced in narrow phase bins (``g_sampling="window"``, :mod:`photon_fields.runtime.photons.phase_window`), g itself
  and its cubic B-spline weights on 16 nodes (~0.1 apart: five nodes could not follow shell's dip in g at -0.6),
  K = 32 photons per target (K = 64's ball reached from lit surfaces into the darker inside: its maps were 2-3 % dark
  on shell and head), the direction features times g (the field is isotropic at g = 0, as the light is; without
  it fields came out dark around g = 0), a harder learning-rate anneal, and 1600 steps of 2048 samples (twice the
  optimizer steps of 800 x 4096 for the same samples: the parts of the field whose targets are small, such as a skull's
  unlit side, converge late; docs/training.md "Both sides"), and the surface input (the medium's surface orientation
  along the camera ray: without it the field spread the light of lit surfaces seen from behind at strong forward
  scattering over all directions, dark where cameras look; docs/training.md). Needs a map of
  :data:`photon_fields.models_spec.photon_map.PHASE_BINS` (what ``pfn-train trace`` makes by default).
- ``cpu-phases``: ``cpu`` as it was before the kernel in g: trains at the map's phases only (the paper's way,
  any map of a few phases), scalar g, the paper's anneal.
- ``cpu-tent``: experimental, ``cpu-phases`` with one tent function of g per phase and training g drawn
  continuously over G's range, targets interpolated between the two phases around g (bench/README.md).
- ``tiny``: a seconds-long configuration for smoke tests.

:class:`photon_fields.train.fit.settings.FitSettings` takes its defaults from :data:`DEFAULT_PRESET`, so the
table is the one source of every default. The measurements behind the ``cpu`` preset are in docs/training.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from photon_fields.models_spec.encoding import DEFAULT_PSI, FieldConfig
from photon_fields.models_spec.hashgrid import PAPER_DIRECTION, PAPER_POSITION, HashGridConfig
from photon_fields.models_spec.surface import surface_cells


@dataclass(frozen=True)
class Preset:
    """A field architecture (its phases come from the photon map) and the settings to train it."""

    position: HashGridConfig
    """Hash encoding of the position (Sec. 3.4)."""
    direction: HashGridConfig
    """Hash encoding of the camera ray's direction on the unit square."""
    hidden_width: int
    """Neurons per hidden layer of the MLP."""
    hidden_layers: int
    """Hidden layers of the MLP."""
    steps: int
    """Training steps."""
    batch: int
    """Samples (x, omega, g) per step, each with a fresh photon-map target."""
    lr: float
    """Adam's learning rate before the decay (:mod:`photon_fields.train.fit.optimizer`)."""
    schedule: str
    """KNN radius schedule: "staggered" (Table 1 by photon count) or "naive" (its final radius throughout)."""
    sampling: str
    """Training positions: "box" (uniform in the volume's box, the paper), "support" (where sigma_t > 0) or
    "visible" (half of them where cameras around the volume see the medium, with the direction they see it from;
    the rest in the support)."""
    k: int = 1024
    """Photons per target estimate (Eq. 5's K). Fewer photons make noisier targets, which the linear loss
    averages without bias, and a smaller ball, which is less biased at dense surfaces and cheaper."""
    loss: str = "linear"
    """Training loss (:mod:`photon_fields.train.fit.loss`): "linear" (relative L2 of the decoded radiance,
    unbiased under noisy targets) or "log" (tcnn's relative L2 of the encoded output, the paper's)."""
    lr_decay_start: float = 0.7
    """Share of the steps after which the learning rate decays (x0.92 per ``lr_decay_every`` steps; the paper:
    0.7)."""
    lr_decay_every: int = 25
    """Steps between two x0.92 decays of the learning rate (the paper: 25)."""
    average: float = 0.0
    """Share of the last training steps whose parameters are averaged into the final field (Polyak-Ruppert
    averaging, :mod:`photon_fields.train.fit.averaging`); 0: the last step's parameters (the paper). Each step
    moves the field towards its batch's noisy targets; the average of the iterates keeps what they agree on."""
    phase_encoding: str = "scalar"
    """How g enters the MLP (:func:`photon_fields.models_spec.encoding.phase_features`): "scalar" (the paper) or
    "tent" (g and one tent function per phase, which lets the bias-free MLP bend at every phase) or "spline" (g and
    the cubic B-spline weights of evenly spaced nodes: smooth in g, so no dip at the nodes)."""
    phase_nodes: int = 5
    """Nodes of the phase features (tents or splines) of a field trained from a kernel in g
    (``g_sampling="window"``), evenly spread over the g it is trained on; a field trained at a map's phases has one
    per phase."""
    direction_gain: str = "none"
    """"none" (the paper) or "g": the direction features times g before the MLP, so that the field is isotropic at
    g = 0, as the light is (:attr:`photon_fields.models_spec.encoding.FieldConfig.direction_gain`)."""
    surface: bool = False
    """Whether the field has the surface input: two columns from the medium's surface orientation at x seen along
    the camera ray, times g (:mod:`photon_fields.models_spec.surface`; its grid is computed from the medium the
    field is fitted to)."""
    g_sampling: str = "discrete"
    """Training g (:mod:`photon_fields.train.fit.targets`): "discrete" (the phases G, the paper), "continuous"
    (uniform over [min G, max G], targets from the two nearest phases' photons) or "mixed" (half of each)."""
    about: str = ""
    """One line for ``--help`` and reports."""


_CPU_PHASES = Preset(HashGridConfig(3, 8, 4, 16, 16, 1.5), HashGridConfig(2, 6, 2, 14, 4, 1.6), 64, 3,
                     steps=800, batch=1 << 12, lr=1e-2, schedule="naive", sampling="support", k=64, average=0.5,
                     about="cpu at the map's phases only (any map of a few phases), scalar g")

PRESETS: dict[str, Preset] = {
    "paper": Preset(PAPER_POSITION, PAPER_DIRECTION, 64, 4, steps=3000, batch=1 << 16, lr=1e-2,
                    schedule="staggered", sampling="box", loss="log",
                    about="Sec. 3.4/3.5 as published (hours on 2 CPU cores)"),
    "cpu": replace(_CPU_PHASES, phase_encoding="spline", g_sampling="window", phase_nodes=16, lr_decay_start=0.5,
                   lr_decay_every=10, sampling="visible", k=32, direction_gain="g", steps=1600, batch=1 << 11,
                   surface=True,
                   about="the default: any g from a kernel in g over a map in narrow phase bins; ~1 min on 2 cores"),
    "cpu-phases": _CPU_PHASES,
    "cpu-tent": replace(_CPU_PHASES, phase_encoding="tent", g_sampling="continuous",
                        about="experimental: cpu-phases with tent phase features and continuous g (bench/README.md)"),
    "tiny": Preset(HashGridConfig(3, 4, 2, 12, 8, 2.0), HashGridConfig(2, 2, 2, 8, 4, 2.0), 16, 1,
                   steps=50, batch=1 << 10, lr=1e-2, schedule="staggered", sampling="box",
                   about="smoke tests: seconds"),
}

#: The preset whose settings are the defaults of FitSettings and pfn-train.
DEFAULT_PRESET = "cpu"

# Defaults of a warm-started update (``pfn-train update``, :mod:`photon_fields.train.fit.update`), for any preset;
# the measurements behind them: docs/training.md ("Updates").
#: Wall-clock budget, seconds (the goal: an updated field in <= 15 s on 2 cores).
UPDATE_BUDGET_S = 15.0
#: Seconds of the budget kept for what comes after training (the log, the loss plot and the bundle's export:
#: 0.5-1.9 s measured on 2 cores), so that the whole update, not only its training, fits the budget.
UPDATE_OUTPUT_RESERVE_S = 1.5
#: Photon records of the retraced map, at most (an earlier map with fewer keeps its count). The retrace, the map's
#: search structures and the validation targets scale with it: 5M (``pfn-train all``'s default) took 16-18 s to
#: retrace alone, more than the budget.
UPDATE_PHOTONS = 1_000_000
#: The retrace stops once it has used this share of the budget left when it starts, if it holds at least
#: :data:`UPDATE_MIN_PHOTONS` records by then (whole chunks of paths: the map is a prefix of the full one's paths).
#: On sparse media a record costs many paths: vortex's 1M took 6-12 s of the 15 s, leaving 1-86 steps.
UPDATE_TRACE_SHARE = 0.4
UPDATE_MIN_PHOTONS = 250_000
#: Step limit (a cold ``cpu`` fit takes 800).
UPDATE_MAX_STEPS = 400
#: The update's constant learning rate as a share of the preset's: 0.15 since 2026-11-26 (0.3 before), which took
#: every transfer-function edit's error to the new map from 1.08-1.20x a cold retrain's to 1.04-1.15x, light edits
#: unchanged (lower shares are slower to follow a moved light).
UPDATE_LR_SHARE = 0.15
#: Steps between two validations (and the parameter-averaging window) of an update.
UPDATE_VAL_EVERY = 25


def field_config_for(preset: Preset, phases: tuple[float, ...], psi: float = DEFAULT_PSI,
                     light_channels: int = 1, volume_shape: tuple[int, ...] | None = None) -> FieldConfig:
    """The field configuration of ``preset`` for a map traced at ``phases``, with ``light_channels`` outputs;
    ``volume_shape``: the volume's, whose surface grid a preset with the surface input sizes (it needs one)."""
    surface = None
    if preset.surface:
        if volume_shape is None:
            raise ValueError("a preset with the surface input needs the volume's shape")
        surface = surface_cells(volume_shape)
    return FieldConfig(preset.position, preset.direction, preset.hidden_width, preset.hidden_layers, psi, phases,
                       preset.phase_encoding, light_channels, preset.direction_gain, surface)
