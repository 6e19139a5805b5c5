"""Training losses on the field's log-encoded output (Eq. 6), one per :data:`LOSSES` entry.

``"log"``, :func:`relative_l2_loss`: tiny-cuda-nn's relative L2 on the *encoded* values (paper Sec. 3.5),
``(pred - target)^2 / (pred.detach()^2 + 0.01)`` averaged over the batch and the 3 channels; the denominator
is a constant for the gradient, as in tcnn. Its minimizer at a point is the mean of the encoded targets, i.e.
the *geometric* mean of the radiance: whatever the network cannot resolve (target noise, detail finer than
its grids, the change between two trained phases g) is averaged in log space and comes out dark.

``"linear"``, :func:`linear_relative_l2_loss`: the same relative L2 on the *decoded* radiance (Eq. 7),
``(L - Q)^2 / (L.detach()^2 + eps^2)`` with ``eps`` 10 % of the batch's mean target. Its minimizer is the
arithmetic mean of the targets, so noisy targets and unresolved variation average to the right brightness
(the estimator neural radiance caching trains with). ``eps`` bounds the weight of dark samples: with a very
small one (1 %) the rare dark samples dominate the gradient, and SGD's own fluctuation of the prediction in the
denominator biased the field bright; with a large one (25 %, until 2026-11-27) the dark parts of the field are
fitted by absolute error, converge late and came out 2-7 % dark on head's unlit side, seen from behind, with a
seed-to-seed spread of 10 % (docs/training.md "Both sides"). The network still outputs Eq. 6's L', so
the bundle and the runtime do not change; only the gradient does.
"""

from __future__ import annotations

import torch

from photon_fields.train.field.network import decode_radiance_torch

RELATIVE_L2_EPS = 0.01  # tcnn RelativeL2: prediction^2 + 1e-2
#: eps of the linear loss, relative to the batch's mean target radiance (scale-free: a light 10x brighter
#: trains the same field, 10x brighter).
LINEAR_EPS_RELATIVE = 0.1
#: The losses FitSettings.loss may name.
LOSSES = ("linear", "log")


def relative_l2_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """tcnn's RelativeL2 on encoded values: mean of (pred - target)^2 / (pred.detach()^2 + 0.01)."""
    return ((pred - target) ** 2 / (pred.detach() ** 2 + RELATIVE_L2_EPS)).mean()


def linear_relative_l2_loss(pred: torch.Tensor, target: torch.Tensor, psi: float, lights: int = 1) -> torch.Tensor:
    """Relative L2 of the decoded radiance: mean of (L - Q)^2 / (L.detach()^2 + eps^2), with L and Q the Eq. 7
    decodings of the encoded ``pred`` and ``target`` and eps = 10 % of mean(Q). With ``lights`` > 1 (one RGB
    output per light, (n, 3 lights)) each light's squared error is divided by the *summed* prediction's square
    and eps taken from the summed targets, and the lights' terms are added: the loss weighs each light's error by
    what it does to the image (the sum), so a light that adds little at a point is not fitted at the cost of the
    others; with one light this is the loss above."""
    L = decode_radiance_torch(pred, psi)
    Q = decode_radiance_torch(target, psi)
    if lights == 1:
        eps = LINEAR_EPS_RELATIVE * float(Q.detach().mean()) + 1e-30
        return ((L - Q) ** 2 / (L.detach() ** 2 + eps * eps)).mean()
    n = L.shape[0]
    parts, targets = L.reshape(n, lights, 3), Q.reshape(n, lights, 3)
    total = parts.detach().sum(dim=1, keepdim=True)
    eps = LINEAR_EPS_RELATIVE * float(targets.detach().sum(dim=1).mean()) + 1e-30
    return ((parts - targets) ** 2 / (total ** 2 + eps * eps)).sum(dim=1).mean()


def field_loss(name: str, pred: torch.Tensor, target: torch.Tensor, psi: float, lights: int = 1) -> torch.Tensor:
    """The loss ``name`` (one of :data:`LOSSES`) of encoded predictions against encoded targets (``lights``: RGB
    outputs per sample, :func:`linear_relative_l2_loss`; the log loss is per channel either way)."""
    if name == "linear":
        return linear_relative_l2_loss(pred, target, psi, lights)
    if name == "log":
        return relative_l2_loss(pred, target)
    raise ValueError(f"unknown loss {name!r} (one of {LOSSES})")
