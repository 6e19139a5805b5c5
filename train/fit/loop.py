"""The training loop: fit a photon field to a photon map (paper Sec. 3.3, 3.5.1).

Every step draws a fresh batch with targets at the KNN schedule's current radius
(:mod:`photon_fields.train.fit.targets`, :mod:`photon_fields.train.fit.schedule`), predicts the log-encoded
radiance (Eq. 6) with :class:`photon_fields.train.field.network.TorchPhotonField` and takes one step of
:class:`photon_fields.train.fit.optimizer.TcnnAdam` on the settings' loss (:mod:`photon_fields.train.fit.loss`).
With ``settings.average`` > 0 the final field is the mean of the parameters over that share of the last steps
(:mod:`photon_fields.train.fit.averaging`); the last validation and checkpoint are of that field.
Settings: :class:`photon_fields.train.fit.settings.FitSettings` (defaults from the presets,
:mod:`photon_fields.train.fit.presets`).

Outputs (run folder, each file written atomically):

- ``checkpoint.pt`` (:mod:`photon_fields.train.fit.checkpoint`), every ``checkpoint_every`` steps and at the end;
- ``log.json``: settings, per-step columns (loss, radius, lr, wall time, seconds waited for the targets and of the
  step, mean photons found), validation history and totals (incl. the time split targets waited / training step,
  and the worker's time computing targets beside the training, ``targets_background_s``);
- ``loss.png`` (:mod:`photon_fields.train.fit.plots`): the loss curve with the schedule's stage changes.

A non-finite loss stops the run with :class:`TrainingDivergedError` (an InputError: one line naming the step
and the lr); the checkpoint of the last save is kept, ``log.json`` and ``loss.png`` record the run up to the
failure.

Threads: torch's and numba's OpenMP pools share the cores; ``photon_fields.runtime`` sets passive waiting
on import (its docstring says why).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch

from photon_fields.models_spec.encoding import MAX_LIGHT_CHANNELS, FieldConfig
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.photons.estimate import check_map_matches_scene, map_for_scene
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.scene.scene import Scene
from photon_fields.train.field.network import TorchPhotonField, decode_radiance_torch
from photon_fields.train.field.surface_grid import medium_surface_grid
from photon_fields.train.fit.averaging import ParameterAverage, averaging_start
from photon_fields.train.fit.checkpoint import save_checkpoint
from photon_fields.train.fit.loss import field_loss
from photon_fields.train.fit.optimizer import TcnnAdam, lr_at
from photon_fields.train.fit.plots import plot_loss
from photon_fields.train.fit.presets import PRESETS, field_config_for
from photon_fields.train.fit.settings import FitSettings
from photon_fields.train.fit.targets import TargetBatch, TargetSampler, check_phase_bins

#: Top-level keys of ``log.json`` (read back by the export for the preset and batch).
LOG_KEYS = ("scene", "scene_fingerprint", "photons", "phases", "settings", "field_config", "schedule",
            "schedule_boundaries", "averaged_from_step", "status", "threads", "parameters", "validation_points",
            "validation_targets_s",
            "per_step", "validation", "totals", "warm_start_from", "stop", "update_time")
"""``warm_start_from``, ``stop`` and ``update_time`` are written only by a warm-started update
(:mod:`photon_fields.train.fit.fine_tune`): the run it started from, why it stopped and where its time went."""


class TrainingDivergedError(InputError):
    """The loss became non-finite (too high a learning rate, usually)."""


def train_step(model: TorchPhotonField, opt: TcnnAdam, pos: torch.Tensor, dirs: torch.Tensor, g: torch.Tensor,
               target: torch.Tensor, lr: float, step: int, loss_name: str = "linear") -> float:
    """One optimization step on encoded targets; returns the loss *before* the step. A non-finite loss
    returns at once, without touching the parameters (the caller decides what to do)."""
    pred = model(pos, dirs, g)
    loss = field_loss(loss_name, pred, target, model.cfg.psi, model.cfg.light_channels)
    value = float(loss.detach())
    if not math.isfinite(value):
        return value
    loss.backward()
    opt.step(lr, step)
    return value


@torch.no_grad()
def validate_field(model: TorchPhotonField, val: TargetBatch, chunk: int = 1 << 14,
                   loss_name: str = "linear") -> dict[str, float]:
    """Validation of a field during its fit (not the image-based evaluation of :mod:`photon_fields.train.eval`):
    quality on held-out support samples: ``val_loss`` (the training loss on L') and ``val_rel_l1``,
    sum |L_pred - Q| / sum Q over samples and channels of the decoded radiance (Eq. 7), the lights' parts summed
    first: the share of the light that is wrong, which is what an image shows."""
    preds = [model(val.pos[i:i + chunk], val.dirs[i:i + chunk], val.g[i:i + chunk])
             for i in range(0, val.pos.shape[0], chunk)]
    pred = torch.cat(preds)
    lights = model.cfg.light_channels
    loss = float(field_loss(loss_name, pred, val.target, model.cfg.psi, lights))
    n = pred.shape[0]
    L = decode_radiance_torch(pred, model.cfg.psi).double().numpy().reshape(n, lights, 3).sum(axis=1)
    q = val.q.reshape(n, lights, 3).sum(axis=1)
    rel = float(np.abs(L - q).sum() / max(float(q.sum()), 1e-300))
    return {"val_loss": loss, "val_rel_l1": rel}


def light_channels_for(pmap: PhotonMap, per_light: bool) -> int:
    """The light channels of a field fitted to ``pmap`` (:attr:`photon_fields.models_spec.encoding.FieldConfig.
    light_channels`): the map's lights when ``per_light`` and it records each photon's light among 2 to
    ``MAX_LIGHT_CHANNELS``; else 1."""
    lights = pmap.light_count
    return lights if per_light and 2 <= lights <= MAX_LIGHT_CHANNELS else 1


def field_sampler(scene: Scene, pmap: PhotonMap, settings: FitSettings,
                  light_channels: int) -> tuple[TargetSampler, FieldConfig]:
    """The target sampler of a fit with ``settings`` on ``pmap`` (its targets computed beside the training; the
    caller closes it) and the field configuration it trains (its preset's architecture, the sampler's phases,
    ``light_channels`` outputs)."""
    preset = PRESETS[settings.preset]
    sampler = TargetSampler(pmap, scene.medium(), k=settings.k, psi=settings.psi, seed=settings.seed,
                            sampling=settings.sampling, g_sampling=settings.g_sampling, lights=light_channels,
                            background=True)
    return sampler, field_config_for(preset, sampler.field_phases(preset.phase_nodes), settings.psi, light_channels,
                                     scene.medium().density.shape)


@contextlib.contextmanager
def deterministic_torch() -> Iterator[None]:
    """Run torch with deterministic algorithms only (restored on exit)."""
    # Every op of the field has a deterministic CPU kernel (the hash-grid scatter is deterministic by
    # construction); the flag makes torch refuse a nondeterministic one instead of silently using it.
    previous = torch.are_deterministic_algorithms_enabled()
    _set_deterministic(True)
    try:
        yield
    finally:
        _set_deterministic(previous)


def _set_deterministic(mode: bool) -> None:
    """``torch.use_deterministic_algorithms(mode)`` for eager torch, without its first call's import of
    ``torch._inductor`` (1.6 s of every fit and update, for a compiler setting: nothing here is compiled).
    torch is pinned (pyproject.toml); should the private setter go, the public call does the same."""
    setter = getattr(torch._C, "_set_deterministic_algorithms", None)
    if setter is None:
        torch.use_deterministic_algorithms(mode)
    else:
        setter(mode, warn_only=False)


@dataclass
class FitResult:
    model: TorchPhotonField
    log: dict[str, Any]
    out_dir: Path
    files: list[Path] = field(default_factory=list)


def fit(scene: Scene, pmap: PhotonMap, out_dir: str | Path, settings: FitSettings | None = None, *,
        progress: bool = True, sampler_hook: Callable[[TargetBatch, int], TargetBatch] | None = None,
        on_progress: Callable[[int, int], None] | None = None) -> FitResult:
    """Train a photon field on ``pmap`` (traced for ``scene``) and write checkpoint, log and plot to ``out_dir``.
    ``on_progress(done, total)`` is called after every step (e.g. a progress file's update).

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
    sampler, cfg = field_sampler(scene, pmap, settings, light_channels_for(pmap, settings.per_light))
    schedule = settings.resolve_schedule(len(pmap))
    total = settings.steps
    boundaries = schedule.boundaries(total)
    torch.manual_seed(settings.seed)
    model = TorchPhotonField(cfg, seed=settings.seed,
                             surface=None if cfg.surface is None else medium_surface_grid(scene.medium()))
    opt = TcnnAdam(model.matrix_parameters(), model.table_parameters())
    val = sampler.validation_set(settings.val_points, schedule.final_radius)
    val_every = settings.val_every or max(1, total // 10)
    average_from = averaging_start(total, settings.average)
    average = ParameterAverage(model)
    setup_s = time.perf_counter() - t_start

    per: dict[str, list[float]] = {k: [] for k in ("step", "loss", "radius", "lr", "wall_s", "targets_s", "step_s",
                                                    "found_mean")}
    log: dict[str, Any] = {
        "scene": scene.name, "scene_fingerprint": scene.fingerprint(), "photons": len(pmap),
        "phases": list(pmap.phases), "settings": settings.to_dict(), "field_config": cfg.to_dict(),
        "schedule": schedule.to_dict(), "schedule_boundaries": boundaries, "status": "running",
        "averaged_from_step": average_from,
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
                "targets_s": targets_s, "targets_background_s": sampler.background_seconds, "train_s": steps_s,
                "targets_s_per_step": targets_s / max(done, 1), "train_s_per_step": steps_s / max(done, 1),
                "samples_per_s": done * settings.batch / max(targets_s + steps_s, 1e-9),
                "final_loss": per["loss"][-1] if per["loss"] else None,
                "final_validation": log["validation"][-1] if log["validation"] else None}

    def write_outputs(done: int, status: str) -> None:
        log["status"] = status
        log["totals"] = summary(done)
        atomic_write_text(log_path, json.dumps(log, indent=1) + "\n")
        plot_loss(log, png)

    bar = progress_bar(total=total, desc="fitting", unit="step", enabled=progress)
    try:
        with deterministic_torch():
            for step in range(total):
                radius = schedule.radius_at(step, total)
                lr = lr_at(step, total, settings.lr, settings.lr_decay_start, settings.lr_decay_every)
                batch = sampler.sample(settings.batch, radius)
                if sampler_hook is not None:
                    batch = sampler_hook(batch, step)
                t0 = time.perf_counter()
                loss_value = train_step(model, opt, batch.pos, batch.dirs, batch.g, batch.target, lr, step,
                                        settings.loss)
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
                if step >= average_from:
                    average.add()
                if done == total:
                    average.apply()  # the field is the average of the last iterates (no-op without averaging)
                if done % val_every == 0 or done == total:
                    log["validation"].append({"step": done, **validate_field(model, val, loss_name=settings.loss)})
                if done % settings.checkpoint_every == 0 and done != total:
                    save_checkpoint(ckpt, model, scene.fingerprint(), done, summary(done))
                    last_ckpt_step = done
                bar.update(1)
                if on_progress is not None:
                    on_progress(done, total)
                bar.set_postfix(loss=f"{loss_value:.4f}", r=f"{radius:.4g}",
                                sps=f"{done * settings.batch / max(train_s + sampler.seconds, 1e-9):,.0f}")
    finally:
        bar.close()
        sampler.close()
    save_checkpoint(ckpt, model, scene.fingerprint(), total, summary(total))
    write_outputs(total, "done")
    return FitResult(model, log, out, [ckpt, log_path, png])


def load_map_for(scene: Scene, path: str | Path) -> tuple[PhotonMap, str | None]:
    """A photon map for fitting ``scene``, and a note or None: a map traced for the scene; or for it with its
    lights' power or colour edited, rescaled exactly (:func:`photon_fields.runtime.photons.estimate.map_for_scene`;
    the note says so); any other map is refused in one line."""
    pmap = PhotonMap.load(path)
    if pmap.scene_fingerprint == scene.fingerprint():
        return pmap, None
    rescaled, _, note = map_for_scene(pmap, scene, force=True)
    if note is None:
        raise InputError(str(path), f"photon map was traced for {pmap.mismatch(scene.fingerprint_parts())}; "
                         "re-trace it for this scene")
    return rescaled, note
