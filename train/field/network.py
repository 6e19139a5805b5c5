"""The photon field network P_phi(x, g, omega) (paper Sec. 3.4, Fig. 5) and the torch twins of Eq. 6 / 7.

:class:`TorchPhotonField` is three modules in a row, as in Fig. 5:

1. encoding: a 3-D hash grid on the normalized position x in [0, 1]^3, a 2-D hash grid on the direction
   in normalized spherical coordinates ([0, 1]^2), the phase features of g (g itself, plus one tent per
   phase with the "tent" encoding) and, with ``cfg.surface``, the surface input's two columns (the grid is the
   ``surface`` buffer, :meth:`TorchPhotonField.set_surface`); concatenated in that order, the direction's
   features times g with ``cfg.direction_gain`` "g" (the field is then isotropic at g = 0, as the light is)
   (:mod:`models_spec.encoding` defines the input conventions, :class:`train.field.hashgrid.HashGridEncoding`
   the hash grids, bit-exact with tiny-cuda-nn);
2. network: a ReLU MLP with ``cfg.hidden_layers`` hidden layers of ``cfg.hidden_width`` neurons and no
   output activation, producing the 3 log-encoded channels L' (Eq. 6), or 3 per light with ``cfg.light_channels`` > 1
   (each light's part of L, which the renderer sums). Like tiny-cuda-nn's
   FullyFusedMLP (what the paper trained with) the linear layers have no biases and are initialized
   Xavier-uniform; the hash tables start uniform in [-1e-4, 1e-4] as in tcnn;
3. decoding: :func:`decode_radiance_torch` (Eq. 7), applied by the caller (the loss works on L').

Parameters
----------
cfg : photon_fields.models_spec.encoding.FieldConfig
    Encodings, MLP size, psi, phases.
seed : int
    Seeds one ``torch.Generator`` that draws, in this order, the position table, the direction table and
    the MLP weights: the same seed gives the same initial parameters, whatever else used torch's RNG.

``forward(pos, dirs, g)`` takes float32 tensors pos (n, 3) from :func:`models_spec.encoding.normalize_position`,
dirs (n, 2) from :func:`photon_fields.models_spec.encoding.direction_input` and g (n, 1), and returns
float32 (n, 3 C) L' (C = ``cfg.light_channels``).

The torch twins :func:`encode_radiance_torch` / :func:`decode_radiance_torch` compute in float64 and round
to float32 once, like the numpy originals, so both sides agree bit for bit (tests/models_spec/test_encoding.py).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from photon_fields.models_spec.encoding import FieldConfig, check_psi, phase_features
from photon_fields.models_spec.surface import check_surface_grid, surface_columns, unit_direction
from photon_fields.train.field.hashgrid import HashGridEncoding


def encode_radiance_torch(L: torch.Tensor, psi: float) -> torch.Tensor:
    """Eq. 6 in torch: float32 ``-log10(L) / psi`` where ``L > 10^-psi``, else 1 (as models_spec.encoding)."""
    p = check_psi(psi)
    lum = L.detach().to(torch.float64)
    keep = lum > 10.0**-p  # False for NaN, as in numpy
    one = torch.ones_like(lum)
    return torch.where(keep, -torch.log10(torch.where(keep, lum, one)) / p, one).to(torch.float32)


def decode_radiance_torch(Lp: torch.Tensor, psi: float) -> torch.Tensor:
    """Eq. 7 in torch: float32 ``10^(-L' psi)`` (differentiable; float64 inside)."""
    p = check_psi(psi)
    return torch.pow(10.0, -Lp.to(torch.float64) * p).to(torch.float32)


class TorchPhotonField(nn.Module):
    """Hash-grid encoded ReLU MLP from (x, omega, g) to log-encoded radiance (see the module docstring)."""

    def __init__(self, cfg: FieldConfig, *, seed: int = 0, surface: np.ndarray | None = None) -> None:
        super().__init__()
        if not isinstance(cfg, FieldConfig):
            raise TypeError(f"cfg must be a FieldConfig, got {type(cfg).__name__}")
        self.cfg = cfg
        gen = torch.Generator().manual_seed(int(seed))
        self.position = HashGridEncoding(cfg.position, generator=gen)
        self.direction = HashGridEncoding(cfg.direction, generator=gen)
        widths = [cfg.input_dims] + [cfg.hidden_width] * cfg.hidden_layers + [cfg.output_dims]
        layers: list[nn.Module] = []
        for i in range(len(widths) - 1):
            lin = nn.Linear(widths[i], widths[i + 1], bias=False)
            with torch.no_grad():
                bound = (6.0 / (widths[i] + widths[i + 1])) ** 0.5  # Xavier-uniform, as tcnn initializes
                lin.weight.uniform_(-bound, bound, generator=gen)
            layers.append(lin)
            if i < len(widths) - 2:
                layers.append(nn.ReLU())
        self.mlp = nn.Sequential(*layers)
        if cfg.phase_dims > 1:
            # The columns of the per-node phase features (tents or splines) start at zero: with random columns
            # every node would carry its own random offset into the hidden layer, and their variance (largest at
            # a node, where one tent alone is 1) came out of the ReLUs as a dip in L at every tent node that
            # training did not remove (docs/training.md).
            phase_end = cfg.input_dims - cfg.surface_dims
            with torch.no_grad():
                layers[0].weight[:, phase_end - cfg.phase_dims + 1:phase_end] = 0.0
        # The surface input's grid (models_spec.surface): data of the scene, not a parameter; kept in the state dict
        # (so in checkpoints) and exported to the bundle. Zeros until set (a checkpoint's load fills it). A field
        # without the input has no such buffer, so the checkpoints written before it existed load unchanged.
        if cfg.surface is not None:
            self.register_buffer("surface", torch.zeros((*cfg.surface, 3), dtype=torch.int8))
        if surface is not None:
            self.set_surface(surface)

    def set_surface(self, grid: np.ndarray) -> None:
        """Set the surface input's grid (int8 (sx, sy, sz, 3) as ``cfg.surface`` says; :mod:`photon_fields.
        train.field.surface_grid` computes it from the medium)."""
        if self.cfg.surface is None:
            raise ValueError("this field has no surface input")
        check_surface_grid(np.asarray(grid), self.cfg.surface)
        with torch.no_grad():
            self.surface.copy_(torch.from_numpy(np.ascontiguousarray(grid)))

    def table_parameters(self) -> list[nn.Parameter]:
        """The hash tables: tcnn's "non-matrix" parameters (sparse gradients, lazily updated by its Adam)."""
        return [self.position.table, self.direction.table]

    def matrix_parameters(self) -> list[nn.Parameter]:
        """The MLP weight matrices."""
        return [p for p in self.mlp.parameters()]

    def phase_features(self, g: torch.Tensor) -> torch.Tensor:
        """The phase columns of the MLP input (:func:`photon_fields.models_spec.encoding.phase_features`). The tent
        encoding is computed by that numpy function itself, so training and the runtime agree bit for bit; g
        needs no gradient."""
        if self.cfg.phase_encoding == "scalar":
            return g.to(torch.float32)
        gn = g.detach().to(torch.float64).reshape(-1).numpy()
        return torch.from_numpy(phase_features(gn, self.cfg.phases, self.cfg.phase_encoding))

    def forward(self, pos: torch.Tensor, dirs: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        n = pos.shape[0]
        if dirs.shape != (n, 2) or g.shape != (n, 1) or pos.shape != (n, 3):
            raise ValueError(f"expected pos (n, 3), dirs (n, 2), g (n, 1); got {tuple(pos.shape)}, "
                             f"{tuple(dirs.shape)}, {tuple(g.shape)}")
        direction = self.direction(dirs)
        if self.cfg.direction_gain == "g":  # models_spec.encoding.direction_gains, in float32 like the runtime
            direction = direction * g.to(torch.float32)
        parts = [self.position(pos), direction, self.phase_features(g)]
        if self.cfg.surface is not None:
            parts.append(self.surface_features(pos, dirs, g))
        return self.mlp(torch.cat(parts, dim=1))

    def surface_features(self, pos: torch.Tensor, dirs: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """The surface input's columns (:func:`photon_fields.models_spec.surface.surface_columns`, computed by that
        numpy function itself: the inputs need no gradient), with d recovered from the direction input."""
        d = unit_direction(dirs.detach().numpy())
        cols = surface_columns(self.surface.numpy(), pos.detach().numpy(), d, g.detach().reshape(-1).numpy())
        return torch.from_numpy(cols)

    def radiance(self, pos: torch.Tensor, dirs: torch.Tensor, g: torch.Tensor,
                 light_scale: torch.Tensor | None = None) -> torch.Tensor:
        """Decoded radiance L (Eq. 7), float32 (n, 3): with C > 1 light channels the sum of the lights' parts (what
        the runtime renders for the scene trained for); ``light_scale`` (3,) or (C, 3): each part times its light's
        factor first (as :meth:`photon_fields.runtime.field.field.PhotonField.query`)."""
        L = decode_radiance_torch(self.forward(pos, dirs, g), self.cfg.psi)
        parts = L.reshape(L.shape[0], self.cfg.light_channels, 3)
        if light_scale is not None:
            parts = parts * light_scale
        return parts.sum(dim=1)
