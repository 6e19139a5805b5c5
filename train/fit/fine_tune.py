"""Warm-started training: continue a trained field on the photon map of an edited scene (``pfn-train update``).

The training step is the cold fit's (:func:`photon_fields.train.fit.loop.train_step`: a fresh batch with Eq. 5
targets per step, Eq. 6 encoding, tcnn's Adam, paper Sec. 3.3 / 3.5), with four differences that make a
short run from a good start work:

- the field starts from the given model (hash tables and MLP of the earlier run), not from a random
  initialization; the optimizer's moments start at zero (a checkpoint does not hold them);
- the KNN radius is the schedule's final radius throughout (Sec. 3.5.2's staggered stages exist to get a
  random field going; a warm field is already past them);
- the learning rate is constant (the caller chooses it, lower than a cold fit's: the field is near its answer)
  and the parameters are averaged over each validation window (Polyak-Ruppert, as
  :mod:`photon_fields.train.fit.averaging` over a cold fit's last half): each validation judges, and the run
  continues from, the mean of the window's iterates;
- the length is not fixed: the field is validated every ``val_every`` steps (and once before the first step,
  which is the earlier field's error on the new scene) and the run stops at the first of: the stopping rule of
  :class:`photon_fields.train.fit.early_stop.PlateauStop` (the validation error stopped improving),
  ``max_steps``, or the wall-clock ``deadline``.

What is kept: the trained field (a validated window mean after >= 1 step) with the lowest validation error; the
earlier field only when no step ran. The earlier field is the answer for another scene, and after a small edit
the validation cannot tell it from the trained ones: its error is dominated by the targets' own noise, and the
first steps of any fine-tune (even at a tenth of the rate, or with the rate ramped up, or the iterates averaged
from the start) raise it by ~2 % on a field already fitted that closely. Keeping the earlier field whenever it
scored lowest meant a chain of small edits was never followed: in ten opacity steps of x0.93 (``bench/
bench_update_flicker.py``) shell kept it at nine and its L_i fell 2.3 % behind the map, blobs at five and 4 %.

Same seed, same steps, same field; the deadline is the one input that depends on the machine (it changes how
many steps run, which ``log.json`` records with the reason the run stopped).

Outputs as :func:`photon_fields.train.fit.loop.fit`'s (``checkpoint.pt``, ``log.json``, ``loss.png``), the log
with two more keys: ``warm_start_from`` (what the caller says the field came from) and ``stop`` (reason, steps,
limits, the rule's parameters) and ``update_time``: where the update's wall time went, by stage (the caller's
stages before the fine-tune, e.g. the retrace, then the index build, the validation targets, the training steps
and the validations), so that a budget that runs out says what used it.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numba
import numpy as np
import torch

from photon_fields.models_spec.surface import surface_cells
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.photons.photon_map import PhotonMap
from photon_fields.runtime.progress import progress_bar
from photon_fields.runtime.scene.scene import Scene
from photon_fields.train.field.network import TorchPhotonField
from photon_fields.train.field.surface_grid import medium_surface_grid
from photon_fields.train.fit.averaging import ParameterAverage
from photon_fields.train.fit.checkpoint import save_checkpoint
from photon_fields.train.fit.early_stop import PlateauStop
from photon_fields.train.fit.loop import (
    FitResult,
    TrainingDivergedError,
    deterministic_torch,
    field_sampler,
    train_step,
    validate_field,
)
from photon_fields.train.fit.optimizer import TcnnAdam
from photon_fields.train.fit.plots import plot_loss
from photon_fields.train.fit.settings import FitSettings

#: Why a fine-tune stopped (``log.json``'s ``stop.reason``).
STOP_REASONS = ("plateau", "max_steps", "budget")


def fine_tune(model: TorchPhotonField, scene: Scene, pmap: PhotonMap, out_dir: str | Path, settings: FitSettings, *,
              max_steps: int, deadline: float, stop: PlateauStop, warm_start_from: dict[str, Any],
              progress: bool = True, on_progress: Callable[[int, int], None] | None = None,
              spent: dict[str, float] | None = None, plot: bool = True) -> FitResult:
    """Continue training ``model`` on ``pmap`` (traced for ``scene``) with ``settings`` (its ``lr``, ``batch``,
    ``k``, ``sampling``, ``g_sampling``, ``loss``, ``seed``, ``val_points`` and ``val_every``; ``steps`` is not
    used) for at most ``max_steps`` steps (0: validate and save the field as it is) and until ``deadline``
    (a :func:`time.perf_counter` value); see the module docstring. Writes checkpoint, log and plot to ``out_dir``
    (which must exist). ``on_progress(done, max_steps)`` is called after every step. ``spent``: seconds the
    caller spent on the same budget before the call, by stage (recorded first in the log's ``update_time``).
    ``plot`` False: the finished run's loss plot is left to the caller (``update_run`` writes it after the bundle)."""
    settings.validate()
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0:
        raise InputError("--max-steps", f"must be an integer >= 0, got {max_steps!r}")
    t_start = time.perf_counter()
    out = Path(out_dir)
    lights = model.cfg.light_channels
    if lights > 1 and lights != pmap.light_count:
        raise InputError("warm start", f"the earlier field keeps {lights} lights apart, the scene has "
                         f"{len(scene.lights)}: train a new field with pfn-train all")
    sampler, cfg = field_sampler(scene, pmap, settings, lights)
    # A field trained before its preset took the direction gain or the surface input keeps its own: the warm start is
    # the earlier field, whose features were fitted with (or without) them.
    surface = None if model.cfg.surface is None else surface_cells(scene.medium().density.shape)
    cfg = replace(cfg, direction_gain=model.cfg.direction_gain, surface=surface)
    want, have = cfg.to_dict(), model.cfg.to_dict()
    if want != have:
        differ = ", ".join(sorted(k for k in {*want, *have} if want.get(k) != have.get(k)))
        raise InputError("warm start", f"the earlier field's architecture is not preset {settings.preset!r}'s for "
                         f"this photon map (its {differ} differ); train a new field with pfn-train all")
    if surface is not None:  # the edited scene's surfaces (a transfer-function edit moves them)
        model.set_surface(medium_surface_grid(scene.medium()))
    schedule = settings.resolve_schedule(len(pmap))
    radius = schedule.final_radius
    torch.manual_seed(settings.seed)
    opt = TcnnAdam(model.matrix_parameters(), model.table_parameters())
    val = sampler.validation_set(settings.val_points, radius)
    val_every = settings.val_every or 25
    setup_s = time.perf_counter() - t_start
    validate_s = [0.0]

    per: dict[str, list[float]] = {k: [] for k in ("step", "loss", "radius", "lr", "wall_s", "targets_s", "step_s",
                                                    "found_mean")}
    log: dict[str, Any] = {
        "scene": scene.name, "scene_fingerprint": scene.fingerprint(), "photons": len(pmap),
        "phases": list(pmap.phases), "settings": settings.to_dict(), "field_config": model.cfg.to_dict(),
        "schedule": schedule.to_dict(), "schedule_boundaries": [0], "status": "running",
        "averaged_from_step": None,
        "threads": {"numba": numba.get_num_threads(), "torch": torch.get_num_threads()},
        "parameters": {"tables": sum(p.numel() for p in model.table_parameters()),
                       "mlp": sum(p.numel() for p in model.matrix_parameters())},
        "validation_points": int(val.pos.shape[0]), "validation_targets_s": val.seconds,
        "per_step": per, "validation": [], "warm_start_from": warm_start_from,
        "stop": {"reason": None, "steps": 0, "max_steps": max_steps, "val_every": val_every,
                 "patience": stop.patience, "min_improvement": stop.min_improvement, "kept_step": None},
    }
    ckpt, log_path, png = out / "checkpoint.pt", out / "log.json", out / "loss.png"
    kept: list[torch.Tensor] = []
    kept_validation: dict[str, Any] = {}

    def summary(done: int) -> dict[str, Any]:
        targets_s, steps_s = float(np.sum(per["targets_s"])), float(np.sum(per["step_s"]))
        return {"steps_done": done, "wall_s": time.perf_counter() - t_start, "setup_s": setup_s,
                "index_build_s": sampler.build_seconds, "targets_s": targets_s,
                "targets_background_s": sampler.background_seconds, "train_s": steps_s,
                "targets_s_per_step": targets_s / max(done, 1), "train_s_per_step": steps_s / max(done, 1),
                "samples_per_s": done * settings.batch / max(targets_s + steps_s, 1e-9),
                "final_loss": per["loss"][-1] if per["loss"] else None,
                "final_validation": kept_validation or None}

    def time_split(done: int) -> dict[str, float]:
        """Seconds by stage: the caller's (``spent``), then this fine-tune's; ``fine_tune_s`` is their sum's
        last part (setup, steps, validations and bookkeeping)."""
        targets_s, steps_s = float(np.sum(per["targets_s"])), float(np.sum(per["step_s"]))
        return {**(spent or {}), "index_build_s": sampler.build_seconds, "validation_targets_s": val.seconds,
                "setup_s": setup_s, "targets_s": targets_s, "train_s": steps_s, "validate_s": validate_s[0],
                "fine_tune_s": time.perf_counter() - t_start}

    def write_outputs(done: int, status: str) -> None:
        log["status"] = status
        log["totals"] = summary(done)
        log["update_time"] = time_split(done)
        atomic_write_text(log_path, json.dumps(log, indent=1) + "\n")
        if plot or status != "done":
            plot_loss(log, png)

    def check(done: int) -> bool:
        """Validate the field after ``done`` steps; keep it if it is the best trained one so far (module docstring,
        "What is kept"); True: stop (plateau)."""
        t = time.perf_counter()
        entry = {"step": done, **validate_field(model, val, loss_name=settings.loss)}
        validate_s[0] += time.perf_counter() - t
        log["validation"].append(entry)
        plateau = stop.add(entry["val_rel_l1"])
        error = entry["val_rel_l1"]
        first_trained = done > 0 and log["stop"]["kept_step"] == 0 and math.isfinite(error)
        if not kept or first_trained or error < kept_validation["val_rel_l1"]:
            kept[:] = [p.detach().clone() for p in model.parameters()]
            kept_validation.clear()
            kept_validation.update(entry)
            log["stop"]["kept_step"] = done
        return plateau

    done = 0
    reason = "max_steps"
    window = ParameterAverage(model)
    bar = progress_bar(total=max_steps, desc="updating", unit="step", enabled=progress)
    try:
        with deterministic_torch():
            stopped = check(0)
            if stopped:  # only with patience 1 and a non-finite start
                reason = "plateau"
            while not stopped and done < max_steps:
                if time.perf_counter() >= deadline:
                    reason = "budget"
                    break
                batch = sampler.sample(settings.batch, radius)
                t0 = time.perf_counter()
                loss_value = train_step(model, opt, batch.pos, batch.dirs, batch.g, batch.target, settings.lr, done,
                                        settings.loss)
                if not math.isfinite(loss_value):
                    write_outputs(done, "diverged")
                    raise TrainingDivergedError("training", f"the loss became {loss_value} at step {done} of the "
                                                f"update (lr {settings.lr:g})")
                dt = time.perf_counter() - t0
                for key, value in (("step", done), ("loss", loss_value), ("radius", radius), ("lr", settings.lr),
                                   ("wall_s", time.perf_counter() - t_start), ("targets_s", batch.seconds),
                                   ("step_s", dt), ("found_mean", float(batch.found.mean()))):
                    per[key].append(value)
                done += 1
                window.add()
                if done % val_every == 0 or done == max_steps:
                    window.apply()  # judge (and continue from) the mean of the window's iterates
                    window = ParameterAverage(model)
                    if check(done):
                        reason = "plateau"
                        stopped = True
                bar.update(1)
                if on_progress is not None:
                    on_progress(done, max_steps)
            if window.count:  # stopped by the deadline inside a window: judge its mean too
                window.apply()
                check(done)
    finally:
        bar.close()
        sampler.close()
    with torch.no_grad():
        for p, k in zip(model.parameters(), kept, strict=True):
            p.copy_(k)
    log["stop"].update(reason=reason, steps=done)
    save_checkpoint(ckpt, model, scene.fingerprint(), done, summary(done))
    write_outputs(done, "done")
    return FitResult(model, log, out, [ckpt, log_path, png])
