"""Training presets: a field architecture and the settings to train it, in one table (:data:`PRESETS`).

- ``paper``: Sec. 3.4/3.5 as published (both encodings 16 levels x 8 features, 2x scale, 2^19 tables, 4 hidden
  layers of 64, batch 2^16, 3000 steps, the Table-1 KNN schedule, samples uniform in the box). Hours on 2
  CPU cores; kept to reproduce the paper.
- ``cpu``: the default, chosen for useful targets per second on 2 cores: samples in the medium's support
  (the renderer never queries empty space), the final radius from the start, small batches and many steps,
  a richer network than its cost suggests because targets, not the network, dominate a step.
- ``cpu-tent``: experimental, ``cpu`` with one tent function of g per phase as extra MLP inputs and training g
  drawn continuously over G's range; it removes the field's tilt across g in G where the plain one has it, but
  its between-phase targets interpolate the earlier bounces and were no better overall (bench/README.md).
- ``tiny``: a seconds-long configuration for smoke tests.

:class:`photon_fields.train.fit.settings.FitSettings` takes its defaults from :data:`DEFAULT_PRESET`, so the
table is the one source of every default. The measurements behind the ``cpu`` preset are in docs/training.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from photon_fields.models_spec.encoding import DEFAULT_PSI, FieldConfig
from photon_fields.models_spec.hashgrid import PAPER_DIRECTION, PAPER_POSITION, HashGridConfig


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
    """Training positions: "box" (uniform in the volume's box, the paper) or "support" (where sigma_t > 0)."""
    k: int = 1024
    """Photons per target estimate (Eq. 5's K). Fewer photons make noisier targets, which the linear loss
    averages without bias, and a smaller ball, which is less biased at dense surfaces and cheaper."""
    loss: str = "linear"
    """Training loss (:mod:`photon_fields.train.fit.loss`): "linear" (relative L2 of the decoded radiance,
    unbiased under noisy targets) or "log" (tcnn's relative L2 of the encoded output, the paper's)."""
    average: float = 0.0
    """Share of the last training steps whose parameters are averaged into the final field (Polyak-Ruppert
    averaging, :mod:`photon_fields.train.fit.averaging`); 0: the last step's parameters (the paper). Each step
    moves the field towards its batch's noisy targets; the average of the iterates keeps what they agree on."""
    phase_encoding: str = "scalar"
    """How g enters the MLP (:func:`photon_fields.models_spec.encoding.phase_features`): "scalar" (the paper) or
    "tent" (g and one tent function per phase, which lets the bias-free MLP bend at every phase)."""
    g_sampling: str = "discrete"
    """Training g (:mod:`photon_fields.train.fit.targets`): "discrete" (the phases G, the paper), "continuous"
    (uniform over [min G, max G], targets from the two nearest phases' photons) or "mixed" (half of each)."""
    about: str = ""
    """One line for ``--help`` and reports."""


_CPU = Preset(HashGridConfig(3, 8, 4, 16, 16, 1.5), HashGridConfig(2, 6, 2, 14, 4, 1.6), 64, 3,
              steps=800, batch=1 << 12, lr=1e-2, schedule="naive", sampling="support", k=64, average=0.5,
              about="provisional CPU default: trace (1M) + fit in about 2 minutes")

PRESETS: dict[str, Preset] = {
    "paper": Preset(PAPER_POSITION, PAPER_DIRECTION, 64, 4, steps=3000, batch=1 << 16, lr=1e-2,
                    schedule="staggered", sampling="box", loss="log",
                    about="Sec. 3.4/3.5 as published (hours on 2 CPU cores)"),
    "cpu": _CPU,
    "cpu-tent": replace(_CPU, phase_encoding="tent", g_sampling="continuous",
                        about="experimental: cpu with tent phase features and continuous g (bench/README.md)"),
    "tiny": Preset(HashGridConfig(3, 4, 2, 12, 8, 2.0), HashGridConfig(2, 2, 2, 8, 4, 2.0), 16, 1,
                   steps=50, batch=1 << 10, lr=1e-2, schedule="staggered", sampling="box",
                   about="smoke tests: seconds"),
}

#: The preset whose settings are the defaults of FitSettings and pfn-train.
DEFAULT_PRESET = "cpu"


def field_config_for(preset: Preset, phases: tuple[float, ...], psi: float = DEFAULT_PSI) -> FieldConfig:
    """The field configuration of ``preset`` for a map traced at ``phases``."""
    return FieldConfig(preset.position, preset.direction, preset.hidden_width, preset.hidden_layers, psi, phases,
                       preset.phase_encoding)
