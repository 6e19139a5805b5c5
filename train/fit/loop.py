"""Fitting a photon field to a photon map (paper Sec. 3.5: loss, optimizer, schedules; Sec. 4.2: timings).

Loop (Sec. 3.3, 3.5.1): every step draws a fresh batch with targets at the KNN schedule's current radius
(:mod:`train.fit.targets`, :mod:`train.fit.schedule`), predicts the log-encoded radiance (Eq. 6) with
:class:`photon_fields.train.field.network.TorchPhotonField` and takes one optimizer step.

Loss: tiny-cuda-nn's ``RelativeL2`` on the encoded outputs, per output value
``(pred - target)^2 / (pred.detach()^2 + 0.01)``, averaged over the batch and the 3 channels (the paper's
"relative mean square error ... applied to each set of outputs individually"; the denominator is a
constant for the gradient, as in tcnn).

Optimizer: :class:`TcnnAdam`, tiny-cuda-nn's Adam (what the paper used): beta1 0.9, beta2 0.99 (paper),
epsilon 1e-15 (tcnn's setting in its own examples), no L2 regularization (paper), bias correction per
parameter, and the hash tables ("non-matrix" parameters in tcnn) updated *lazily*: an entry whose
gradient is exactly 0 in a step (no sample touched it) keeps its value and moments and does not
advance its step count. The MLP matrices always step. Learning rate: ``lr`` until 70 % of the run,
then x0.92 at that step and every 25 steps after it (tcnn's ExponentialDecay semantics, Sec. 3.5.1).

Learning rate. The paper's "9^-4" is ambiguous (9e-4? 9^-4 = 1.5e-4?). Sweep with the ``cpu`` preset's
architecture, 1M-photon maps, 300 steps x 2^14 samples, naive schedule (r = 5 %), box sampling, seed 0;
validation on 8192 held-out points in the support at r = 5 % (:func:`evaluate`; lower is better):

========  ===========================  ===========================
lr        blobs: val loss / rel. L1    vortex: val loss / rel. L1
========  ===========================  ===========================
1e-3      0.0506 / 0.437               0.154 / 0.924
3e-3      0.0241 / 0.279               0.0372 / 0.437
**1e-2**  **0.0170 / 0.242**           **0.0243 / 0.354**
3e-2      0.0211 / 0.284               0.0294 / 0.387
========  ===========================  ===========================

1e-2 (also tcnn's usual hash-grid rate) is the default of every preset; 9e-4 would sit at the slow end.

Presets (:data:`PRESETS`)
-------------------------
``paper``: Sec. 3.4/3.5 as published: both encodings 16 levels x 8 features, 2x scale, 2^19 tables
(102 M table entries), 4 hidden layers of 64, batch 2^16, 3000 steps, Table-1 schedule, box sampling.
``cpu``: the provisional CPU default (below). ``tiny``: a seconds-long smoke-test configuration.

Measured per step, 2 threads, load ~1.3-1.5 (another job used part of a core), OMP_WAIT_POLICY=PASSIVE:

==================================  =======================  ==============================================
preset, batch                       training step            targets (vortex / blobs / shell)
==================================  =======================  ==============================================
paper, 2^16 (box, r = 0.25 % ...)   0.93-0.98 s (fwd 0.2,    r 0.25 %: 80 / 74 / 55 ms, 0.5 %: 85 / 87 / 55,
                                    bwd 0.6, Adam 0.12)      2.5 %: 194 / 129 / 116, 5 %: 572 / 275 / 293
cpu, 2^12 (support, r = 5 %)        23 ms                    117 / 62 / 66 ms
==================================  =======================  ==============================================

Paper preset run to the end on vortex (1M photons, seed 0; ``bench/bench_training.py --configs cpu,paper``):
6462 s under ~1 core of foreign load, validation relative L1 0.179, field L_i relative L2 on held-out views
0.224 in G; the cpu preset reaches 0.113 / 0.140 in 173 s on the same map: 0.63x the paper preset's error.

So the paper preset is training-bound (~1.1 s/step, ~55 min for 3000 steps, 3.1 GB RSS, a 407 MB
checkpoint) and the cpu preset target-bound (targets are 73-84 % of its step). ``pfn-train all`` with the
cpu preset, 1M photons: vortex 118 s end to end (trace 7.9 s, fit 103.5 s), shell 83 s.

How the provisional ``cpu`` preset was chosen (1M-photon maps, lr 1e-2, seed 0; validation relative L1
error on 8192 support points at r = 5 %, at the wall time given; one run each, loaded machine, so
differences below ~5 % are noise; the reference itself is noisy: two independent 1M maps differ by
0.133 (vortex) / 0.149 (blobs), i.e. a perfect field would score ~0.09 / ~0.10):

- sampling and schedule, 600 x 2^14, cpu v0 architecture (8x2 levels, 2^15 tables; directions 4x2):
  vortex box/naive 0.217 @130 s, box/staggered 0.383 @69 s, support/naive 0.158 @84 s (0.136 @302 s),
  support/staggered 0.227 @54 s (naive 0.216 @53 s), 0.152 @137 s; blobs box/naive 0.182 @83 s,
  box/staggered 0.271 @58 s, support/naive 0.173 @100 s, support/staggered 0.177 @84 s. Support sampling
  wins on vortex (98 % empty) and ties on blobs; the Table-1 schedule's first two stages teach nothing
  (validation ~1.0 until r reaches 2.5 %), naive is as good or better at equal time;
- batch at equal time (support, naive): vortex at ~150 s 0.137 (2^12), 0.137 (2^13), ~0.145 (2^14);
  blobs 0.133 @106 s (2^12) vs 0.151 @144 s (2^13): small batches, many steps;
- architecture, 800 x 2^12: v0 vortex 0.135 @110 s / blobs 0.139 @62 s; positions 8x4 features, 2^16
  tables: 0.128 / 0.130; directions 6 levels (N_min 4, b 1.6, 2^14) + 3 hidden layers: 0.124 / 0.133;
  both (the preset): **0.112 @108 s / 0.120 @70 s**.

Threads: torch's and numba's OpenMP pools both spin after every parallel region; on 2 cores with any
other load they steal each other's core. 150 cpu-preset steps on vortex: 25 s (default policy) vs 26 s
(``OMP_WAIT_POLICY=PASSIVE``) on an idle machine, 48 s vs 34 s next to one busy-looping process (training
step 80 vs 30 ms); a toy fit (batch 1024) next to two other jobs: 63.7 s vs 3.4 s. ``pfn-train`` sets
PASSIVE unless the user chose a policy; it must be in the environment before torch or numba load
libgomp, so library users export it themselves.

Outputs (run folder, each file written atomically)
--------------------------------------------------
- ``checkpoint.pt``: ``torch.save`` of a dict: format, version, ``state_dict``, ``field_config``
  (:meth:`photon_fields.models_spec.encoding.FieldConfig.to_dict`), ``scene_fingerprint``, ``phases``, ``step`` (steps
  done), ``summary``; saved every ``checkpoint_every`` steps and at the end;
- ``log.json``: settings, per-step columns (loss, radius, lr, wall time, target and step seconds, mean
  photons found), validation history and totals (incl. the time split targets / training step);
- ``loss.png``: the loss curve with vertical lines at the schedule's stage changes.

A non-finite loss stops the run with :class:`TrainingDivergedError` (an :class:`runtime.errors.InputError`: one
line naming the step and the lr); the checkpoint of the last save is kept, ``log.json`` and ``loss.png``
record the run up to the failure.
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch
from numba import njit, prange
from tqdm import tqdm

from photon_fields.models_spec.encoding import DEFAULT_PSI, FieldConfig
from photon_fields.models_spec.hashgrid import PAPER_DIRECTION, PAPER_POSITION, HashGridConfig
from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_path, atomic_write_text
from photon_fields.runtime.photons.estimate import DEFAULT_K, check_map_matches_scene
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.scene.scene import Scene
from photon_fields.train.field.network import TorchPhotonField, decode_radiance_torch
from photon_fields.train.fit.schedule import KnnSchedule, default_schedule, naive_schedule
from photon_fields.train.fit.targets import SAMPLING_MODES, TargetBatch, TargetSampler, check_phase_bins

CHECKPOINT_FORMAT = "photon-fields/checkpoint"
CHECKPOINT_VERSION = 1
#: The keys of a checkpoint's dict (all written, all required when read).
CHECKPOINT_KEYS = ("format", "version", "state_dict", "field_config", "scene_fingerprint", "phases", "step", "summary")
#: Top-level keys of ``log.json`` (read back by the export for the preset and batch).
LOG_KEYS = ("scene", "scene_fingerprint", "photons", "phases", "settings", "field_config", "schedule",
            "schedule_boundaries", "status", "threads", "parameters", "validation_points", "validation_targets_s",
            "per_step", "validation", "totals")
RELATIVE_L2_EPS = 0.01  # tcnn RelativeL2: prediction^2 + 1e-2
ADAM_BETAS = (0.9, 0.99)
ADAM_EPS = 1e-15
LR_DECAY = 0.92
LR_DECAY_EVERY = 25
LR_DECAY_START = 0.7


# ----------------------------------------------------------------------------------------------------
# Presets
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Preset:
    """A field architecture (phases filled in from the map) and training settings."""

    position: HashGridConfig
    direction: HashGridConfig
    hidden_width: int
    hidden_layers: int
    steps: int
    batch: int
    lr: float
    schedule: str  # "staggered" (Table 1 by photon count) or "naive" (its final radius throughout)
    sampling: str  # "box" (paper) or "support"
    about: str = ""


PRESETS: dict[str, Preset] = {
    "paper": Preset(PAPER_POSITION, PAPER_DIRECTION, 64, 4, steps=3000, batch=1 << 16, lr=1e-2,
                    schedule="staggered", sampling="box",
                    about="Sec. 3.4/3.5 as published (hours on 2 CPU cores)"),
    # Provisional CPU default, from quick measurements on vortex and blobs (1M photons, 2 cores; module
    # docstring). Targets dominate a step (~110 ms of ~130 ms on vortex at 2^12), so the choices are about
    # useful targets per second: samples in the support (empty space is 98 % of vortex's box), the
    # final radius from the start, small batches and many steps; the network can be richer at ~no cost.
    "cpu": Preset(HashGridConfig(3, 8, 4, 16, 16, 1.5), HashGridConfig(2, 6, 2, 14, 4, 1.6), 64, 3,
                  steps=800, batch=1 << 12, lr=1e-2, schedule="naive", sampling="support",
                  about="provisional CPU default: trace (1M) + fit in about 2 minutes"),
    "tiny": Preset(HashGridConfig(3, 4, 2, 12, 8, 2.0), HashGridConfig(2, 2, 2, 8, 4, 2.0), 16, 1,
                   steps=50, batch=1 << 10, lr=1e-2, schedule="staggered", sampling="box",
                   about="smoke tests: seconds"),
}


def field_config_for(preset: Preset, phases: tuple[float, ...], psi: float = DEFAULT_PSI) -> FieldConfig:
    return FieldConfig(preset.position, preset.direction, preset.hidden_width, preset.hidden_layers, psi, phases)


# ----------------------------------------------------------------------------------------------------
# Optimizer, loss, learning rate
# ----------------------------------------------------------------------------------------------------


@njit(cache=True, parallel=True)
def _adam_kernel(param: np.ndarray, grad: np.ndarray, m: np.ndarray, v: np.ndarray, steps: np.ndarray,
                 corr: np.ndarray, lr: np.float32, b1: np.float32, b2: np.float32, one_b1: np.float32,
                 one_b2: np.float32, eps: np.float32, lazy: bool) -> None:
    # tcnn's adam_step, float32, elementwise (so the result does not depend on the thread count).
    for i in prange(param.shape[0]):
        gi = grad[i]
        if lazy and gi == 0.0:
            continue
        mi = b1 * m[i] + one_b1 * gi
        vi = b2 * v[i] + one_b2 * (gi * gi)
        m[i] = mi
        v[i] = vi
        t = steps[i] + 1
        steps[i] = t
        param[i] = param[i] - (lr * corr[t]) / (np.sqrt(vi) + eps) * mi


class TcnnAdam:
    """tiny-cuda-nn's Adam (module docstring): lazy on the hash tables, dense on the MLP matrices.

    ``step(lr)`` applies one update with learning rate ``lr`` from the gradients in ``.grad`` and then
    drops them (``.grad = None``: the hash-grid backward allocates lazily zeroed pages, cheaper than
    zeroing). State: float32 first/second moments and int32 per-entry step counts."""

    def __init__(self, matrix: list[torch.nn.Parameter], tables: list[torch.nn.Parameter], *,
                 betas: tuple[float, float] = ADAM_BETAS, eps: float = ADAM_EPS) -> None:
        self.groups = [(p, False) for p in matrix] + [(p, True) for p in tables]
        self.b1, self.b2, self.eps = float(betas[0]), float(betas[1]), float(eps)
        self.state = [(np.zeros(p.numel(), np.float32), np.zeros(p.numel(), np.float32),
                       np.zeros(p.numel(), np.int32)) for p, _ in self.groups]
        self._corr = np.zeros(1, np.float32)

    def _correction(self, max_step: int) -> np.ndarray:
        # sqrt(1 - b2^t) / (1 - b1^t) for t = 1..max_step (tcnn computes it per entry with powf).
        if self._corr.shape[0] <= max_step:
            t = np.arange(max(2 * max_step, 64) + 1, dtype=np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                c = np.sqrt(1.0 - self.b2**t) / (1.0 - self.b1**t)
            c[0] = 0.0
            self._corr = c.astype(np.float32)
        return self._corr

    def step(self, lr: float, step_index: int) -> None:
        corr = self._correction(step_index + 1)
        f32 = np.float32
        for (p, lazy), (m, v, steps) in zip(self.groups, self.state, strict=True):
            if p.grad is None:
                continue
            g = p.grad.detach().to(torch.float32).contiguous().view(-1).numpy()
            _adam_kernel(p.detach().view(-1).numpy(), g, m, v, steps, corr, f32(lr), f32(self.b1), f32(self.b2),
                         f32(1.0 - self.b1), f32(1.0 - self.b2), f32(self.eps), lazy)
            p.grad = None


def relative_l2_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """tcnn's RelativeL2: mean of (pred - target)^2 / (pred.detach()^2 + 0.01)."""
    return ((pred - target) ** 2 / (pred.detach() ** 2 + RELATIVE_L2_EPS)).mean()


def train_step(model: TorchPhotonField, opt: TcnnAdam, pos: torch.Tensor, dirs: torch.Tensor, g: torch.Tensor,
               target: torch.Tensor, lr: float, step: int) -> float:
    """One optimization step on encoded targets; returns the loss *before* the step. A non-finite loss
    returns at once, without touching the parameters (the caller decides what to do)."""
    pred = model(pos, dirs, g)
    loss = relative_l2_loss(pred, target)
    value = float(loss.detach())
    if not math.isfinite(value):
        return value
    loss.backward()
    opt.step(lr, step)
    return value


def lr_at(step: int, total: int, lr: float) -> float:
    """Learning rate at 0-based ``step``: x0.92 at ``round(0.7 total)`` and every 25 steps after it."""
    start = int(math.floor(LR_DECAY_START * total + 0.5))
    if step < start:
        return lr
    return lr * LR_DECAY ** ((step - start) // LR_DECAY_EVERY + 1)


# ----------------------------------------------------------------------------------------------------
# Settings, evaluation, outputs
# ----------------------------------------------------------------------------------------------------


@dataclass
class FitSettings:
    """Everything a fit needs besides the scene and the map. Build it with :meth:`from_preset` (the
    defaults here equal the ``cpu`` preset); ``schedule`` overrides ``schedule_kind`` with any
    :class:`photon_fields.train.fit.schedule.KnnSchedule`."""

    preset: str = "cpu"
    steps: int = 800
    batch: int = 1 << 12
    lr: float = 1e-2
    k: int = DEFAULT_K
    schedule: KnnSchedule | None = None  # None: from ``schedule_kind`` and the photon count
    schedule_kind: str = "naive"
    sampling: str = "support"
    seed: int = 0
    checkpoint_every: int = 500
    val_points: int = 1 << 13
    val_every: int = 0  # 0: about 10 evaluations per run
    psi: float = DEFAULT_PSI

    @classmethod
    def from_preset(cls, name: str, **overrides: Any) -> FitSettings:
        if name not in PRESETS:
            raise InputError("--preset", f"unknown preset {name!r} (available: {', '.join(PRESETS)})")
        p = PRESETS[name]
        base = cls(preset=name, steps=p.steps, batch=p.batch, lr=p.lr, schedule_kind=p.schedule,
                   sampling=p.sampling)
        return replace(base, **{k: v for k, v in overrides.items() if v is not None})

    def validate(self) -> None:
        if self.preset not in PRESETS:
            raise InputError("--preset", f"unknown preset {self.preset!r} (available: {', '.join(PRESETS)})")
        for name, v, hi in (("--steps", self.steps, 10**7), ("--batch", self.batch, 1 << 22), ("--k", self.k, 1 << 16),
                            ("--checkpoint-every", self.checkpoint_every, 10**9),
                            ("validation points", self.val_points, 1 << 22)):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= hi:
                raise InputError(name, f"must be an integer in [1, {hi}], got {v!r}")
        if not (math.isfinite(self.lr) and 0 < self.lr <= 10):
            raise InputError("--lr", f"must be in (0, 10], got {self.lr}")
        if self.schedule_kind not in ("staggered", "naive"):
            raise InputError("--schedule", f"must be 'staggered' or 'naive', got {self.schedule_kind!r}")
        if self.sampling not in SAMPLING_MODES:
            raise InputError("--sampling", f"must be one of {SAMPLING_MODES}, got {self.sampling!r}")
        if self.val_every < 0:
            raise InputError("validation interval", f"must be >= 0, got {self.val_every}")

    def resolve_schedule(self, photons: int) -> KnnSchedule:
        if self.schedule is not None:
            return self.schedule
        staggered = default_schedule(photons)
        return staggered if self.schedule_kind == "staggered" else naive_schedule(staggered.radii_percent[-1])

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["schedule"] = self.schedule.to_dict() if self.schedule is not None else None
        return d


class TrainingDivergedError(InputError):
    """The loss became non-finite (too high a learning rate, usually)."""


@torch.no_grad()
def evaluate(model: TorchPhotonField, val: TargetBatch, chunk: int = 1 << 14) -> dict[str, float]:
    """Quality on held-out support samples: ``val_loss`` (the training loss on L') and ``val_rel_l1``,
    sum |L_pred - Q| / sum Q over samples and channels of the decoded radiance (Eq. 7): the share of the
    light that is wrong, which is what an image shows."""
    preds = [model(val.pos[i:i + chunk], val.dirs[i:i + chunk], val.g[i:i + chunk])
             for i in range(0, val.pos.shape[0], chunk)]
    pred = torch.cat(preds)
    loss = float(relative_l2_loss(pred, val.target))
    L = decode_radiance_torch(pred, model.cfg.psi).double().numpy()
    rel = float(np.abs(L - val.q).sum() / max(float(val.q.sum()), 1e-300))
    return {"val_loss": loss, "val_rel_l1": rel}


def save_checkpoint(path: Path, model: TorchPhotonField, scene_fp: str, step: int,
                    summary: dict[str, Any]) -> None:
    """Write the field's weights, its config, the scene fingerprint and the run summary atomically."""
    payload = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "state_dict": model.state_dict(),
               "field_config": model.cfg.to_dict(), "scene_fingerprint": scene_fp,
               "phases": list(model.cfg.phases), "step": int(step), "summary": summary}
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)


def load_checkpoint(path: str | Path,
                    expected_fingerprint: str | None = None) -> tuple[TorchPhotonField, dict[str, Any]]:
    """Rebuild the field of a ``checkpoint.pt`` (refusing another scene's with ``expected_fingerprint``).
    Its metadata is as strict as the JSON files: unknown or missing keys, a field config that does not
    parse or weights that do not fit it are one-line errors naming the file."""
    p = Path(path)
    try:
        data = torch.load(p, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError, ValueError, EOFError) as exc:
        raise InputError(str(p), f"not a readable checkpoint: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise InputError(str(p), "not a photon-field checkpoint")
    if data.get("version") != CHECKPOINT_VERSION:
        raise InputError(str(p), f"checkpoint version {data.get('version')!r} is not supported")
    check_keys(data, CHECKPOINT_KEYS, str(p), required=CHECKPOINT_KEYS)
    if expected_fingerprint is not None and data.get("scene_fingerprint") != expected_fingerprint:
        raise InputError(str(p), "checkpoint was trained for another scene (fingerprint mismatch)")
    try:
        model = TorchPhotonField(FieldConfig.from_dict(data["field_config"]))
        model.load_state_dict(data["state_dict"])
    except (ValueError, TypeError, KeyError, RuntimeError) as exc:
        raise InputError(str(p), f"field_config or state_dict unusable: {' '.join(str(exc).split())[:300]}") from None
    return model, data


def finished_run(run_dir: str | Path, settings: FitSettings) -> dict[str, Any] | None:
    """The log of a finished fit in ``run_dir`` (status done, checkpoint present) made with exactly these
    settings, else None: lets benchmarks and the evaluation reuse a run instead of training it again."""
    run = Path(run_dir)
    try:
        log = json.loads((run / "log.json").read_text())
    except (OSError, ValueError):
        return None
    if log.get("status") != "done" or not (run / "checkpoint.pt").exists():
        return None
    return log if log.get("settings") == json.loads(json.dumps(settings.to_dict())) else None


def plot_loss(log: dict[str, Any], path: Path) -> None:
    """Loss curve (log scale, raw and smoothed), validation loss, vertical lines at stage changes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per = log["per_step"]
    steps = np.asarray(per["step"], dtype=np.int64)
    loss = np.asarray(per["loss"], dtype=np.float64)
    fig, ax = plt.subplots(figsize=(8, 4.5), dpi=100)
    if steps.size:
        ax.plot(steps, loss, lw=0.6, alpha=0.35, color="C0", label="training loss")
        w = max(1, min(25, steps.size // 10))
        if steps.size >= w > 1:
            smooth = np.convolve(loss, np.ones(w) / w, mode="valid")
            ax.plot(steps[w - 1:], smooth, lw=1.5, color="C0", label=f"training loss ({w}-step mean)")
    val = log.get("validation", [])
    if val:
        ax.plot([v["step"] for v in val], [v["val_loss"] for v in val], "o-", ms=4, color="C3",
                label="validation loss (support, final radius)")
    for b, r in zip(log["schedule_boundaries"][1:], log["schedule"]["stages"][1:], strict=False):
        ax.axvline(b, color="0.5", ls="--", lw=0.8)
        ax.text(b, 0.99, f" r={r['radius_percent']:.3g}%", transform=ax.get_xaxis_transform(), va="top", fontsize=8)
    if np.all(loss[np.isfinite(loss)] > 0) and np.isfinite(loss).any():
        ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("relative L2 (encoded)")
    ax.set_title(f"{log['scene']} - preset {log['settings']['preset']}, batch {log['settings']['batch']}, "
                 f"lr {log['settings']['lr']:g}")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


@contextlib.contextmanager
def _deterministic_torch() -> Iterator[None]:
    # Every op of the field has a deterministic CPU kernel (the hash-grid scatter is deterministic by
    # construction); the flag makes torch refuse a nondeterministic one instead of silently using it.
    previous = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous)


# ----------------------------------------------------------------------------------------------------
# The loop
# ----------------------------------------------------------------------------------------------------


@dataclass
class FitResult:
    model: TorchPhotonField
    log: dict[str, Any]
    out_dir: Path
    files: list[Path] = field(default_factory=list)


def fit(scene: Scene, pmap: PhotonMap, out_dir: str | Path, settings: FitSettings | None = None, *,
        progress: bool = True, sampler_hook: Callable[[TargetBatch, int], TargetBatch] | None = None) -> FitResult:
    """Train a photon field on ``pmap`` (traced for ``scene``) and write checkpoint, log and plot to ``out_dir``.

    ``sampler_hook(batch, step) -> batch`` may replace a batch (tests use it to inject a non-finite target)."""
    settings = settings or FitSettings.from_preset("cpu")
    settings.validate()
    check_map_matches_scene(pmap, scene)
    check_phase_bins(pmap)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError("--out", f"cannot create the folder {str(out)!r}: {exc.strerror or exc}") from None
    if not out.is_dir():
        raise InputError("--out", f"{str(out)!r} is not a folder")

    t_start = time.perf_counter()
    preset = PRESETS[settings.preset]
    cfg = field_config_for(preset, tuple(pmap.phases), settings.psi)
    schedule = settings.resolve_schedule(len(pmap))
    total = settings.steps
    boundaries = schedule.boundaries(total)
    torch.manual_seed(settings.seed)
    model = TorchPhotonField(cfg, seed=settings.seed)
    opt = TcnnAdam(model.matrix_parameters(), model.table_parameters())
    sampler = TargetSampler(pmap, scene.medium(), k=settings.k, psi=cfg.psi, seed=settings.seed,
                            sampling=settings.sampling)
    val = sampler.validation_set(settings.val_points, schedule.final_radius)
    val_every = settings.val_every or max(1, total // 10)
    setup_s = time.perf_counter() - t_start

    per: dict[str, list[float]] = {k: [] for k in ("step", "loss", "radius", "lr", "wall_s", "targets_s", "step_s",
                                                    "found_mean")}
    log: dict[str, Any] = {
        "scene": scene.name, "scene_fingerprint": scene.fingerprint(), "photons": len(pmap),
        "phases": list(pmap.phases), "settings": settings.to_dict(), "field_config": cfg.to_dict(),
        "schedule": schedule.to_dict(), "schedule_boundaries": boundaries, "status": "running",
        "threads": {"numba": numba.get_num_threads(), "torch": torch.get_num_threads()},
        "parameters": {"tables": sum(p.numel() for p in model.table_parameters()),
                       "mlp": sum(p.numel() for p in model.matrix_parameters())},
        "validation_points": int(val.pos.shape[0]), "validation_targets_s": val.seconds,
        "per_step": per, "validation": [],
    }
    ckpt, log_path, png = out / "checkpoint.pt", out / "log.json", out / "loss.png"
    last_ckpt_step: int | None = None
    train_s = 0.0

    def summary(done: int) -> dict[str, Any]:
        wall = time.perf_counter() - t_start
        targets_s = float(np.sum(per["targets_s"]))
        steps_s = float(np.sum(per["step_s"]))
        return {"steps_done": done, "wall_s": wall, "setup_s": setup_s, "index_build_s": sampler.build_seconds,
                "targets_s": targets_s, "train_s": steps_s,
                "targets_s_per_step": targets_s / max(done, 1), "train_s_per_step": steps_s / max(done, 1),
                "samples_per_s": done * settings.batch / max(targets_s + steps_s, 1e-9),
                "final_loss": per["loss"][-1] if per["loss"] else None,
                "final_validation": log["validation"][-1] if log["validation"] else None}

    def write_outputs(done: int, status: str) -> None:
        log["status"] = status
        log["totals"] = summary(done)
        atomic_write_text(log_path, json.dumps(log, indent=1) + "\n")
        plot_loss(log, png)

    bar = tqdm(total=total, desc="fitting", unit="step", disable=not progress, leave=False)
    try:
        with _deterministic_torch():
            for step in range(total):
                radius = schedule.radius_at(step, total)
                lr = lr_at(step, total, settings.lr)
                batch = sampler.sample(settings.batch, radius)
                if sampler_hook is not None:
                    batch = sampler_hook(batch, step)
                t0 = time.perf_counter()
                loss_value = train_step(model, opt, batch.pos, batch.dirs, batch.g, batch.target, lr, step)
                if not math.isfinite(loss_value):
                    write_outputs(step, "diverged")
                    kept = (f"kept the checkpoint of step {last_ckpt_step} ({ckpt})" if last_ckpt_step is not None
                            else "no checkpoint had been written yet")
                    raise TrainingDivergedError("training", f"the loss became {loss_value} at step {step} (lr {lr:g}); "
                                           f"{kept}; try a lower --lr")
                dt = time.perf_counter() - t0
                train_s += dt
                per["step"].append(step)
                per["loss"].append(loss_value)
                per["radius"].append(radius)
                per["lr"].append(lr)
                per["wall_s"].append(time.perf_counter() - t_start)
                per["targets_s"].append(batch.seconds)
                per["step_s"].append(dt)
                per["found_mean"].append(float(batch.found.mean()))
                done = step + 1
                if done % val_every == 0 or done == total:
                    log["validation"].append({"step": done, **evaluate(model, val)})
                if done % settings.checkpoint_every == 0 and done != total:
                    save_checkpoint(ckpt, model, scene.fingerprint(), done, summary(done))
                    last_ckpt_step = done
                bar.update(1)
                bar.set_postfix(loss=f"{loss_value:.4f}", r=f"{radius:.4g}",
                                sps=f"{done * settings.batch / max(train_s + sampler.seconds, 1e-9):,.0f}")
    finally:
        bar.close()
    save_checkpoint(ckpt, model, scene.fingerprint(), total, summary(total))
    write_outputs(total, "done")
    return FitResult(model, log, out, [ckpt, log_path, png])


def load_map_for(scene: Scene, path: str | Path) -> PhotonMap:
    """Load a photon map and refuse one traced for another scene, in one line."""
    return PhotonMap.load(path, expected_fingerprint=scene.fingerprint(), expected_parts=scene.fingerprint_parts())
