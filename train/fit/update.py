"""An updated field for an edited scene, seconds after the edit (``pfn-train update RUN --scene NEW --out NEWRUN``).

A transfer-function or light edit changes the light in the volume but not the volume, so the earlier run's
field is a good start for the new one. :func:`update_run`:

1. reads RUN (:func:`read_run`): its checkpoint, ``log.json`` (settings and preset), ``domain.json`` (world
   box, per-part scene fingerprints) and, if present, ``map.npz``'s metadata (photon count, phases, max bounces
   and seed of the map the field was trained on; :func:`photon_fields.runtime.photons.photon_map.read_header`
   reads them without the photons, which took ~2 s for a 5M map);
2. refuses, before writing anything, an update it cannot do well (:func:`check_update`): another volume (the
   ``volume`` part of the fingerprint or the world box differs), a NEW that leaves nothing visible (zero
   opacity everywhere, no light power reaching the volume), a budget <= 0, NEWRUN equal to RUN or holding an
   earlier run (without ``force``);
3. retraces the photon map for NEW with RUN's map settings and seed, with at most
   :data:`photon_fields.train.fit.presets.UPDATE_PHOTONS` records (the retrace, the map's search structures and
   the validation targets all scale with the count; docs/training.md "Updates" has the measurements), and for at
   most :data:`photon_fields.train.fit.presets.UPDATE_TRACE_SHARE` of the budget left (once it holds
   :data:`photon_fields.train.fit.presets.UPDATE_MIN_PHOTONS`: on sparse media a record costs many paths) (Alg. 1,
   :func:`photon_fields.train.photons.tracing.trace_photons`): path i uses random stream i of the seed, so
   every path of the new map starts like the old map's path i and departs from it only where the edit
   changes what it meets: the new map is correlated with the old one, and the field is asked to learn the
   difference, not new noise. An edit of the transfer function's albedo alone is not retraced: RUN's map is
   reweighted exactly and thinned to the same count (:func:`reweighted_map`,
   :mod:`photon_fields.runtime.photons.albedo_reweight`; its paths, the most correlated map there is);
4. warm-starts from RUN's field and trains on the new map until the validation error stops improving, the
   step limit or the time budget (:func:`photon_fields.train.fit.fine_tune.fine_tune`), at the final KNN
   radius and :data:`photon_fields.train.fit.presets.UPDATE_LR_SHARE` of the preset's learning rate;
5. writes NEWRUN as ``pfn-train all`` does (``map.npz``, ``checkpoint.pt``, ``log.json``, ``loss.png``,
   ``domain.json``, ``field.pfn``); the bundle's training summary records the validation error reached, and
   NEWRUN can itself be updated.

RUN is only read. The budget counts the wall time from the call (``pfn-train update``: from the process's start) to
the written bundle: training stops
:data:`photon_fields.train.fit.presets.UPDATE_OUTPUT_RESERVE_S` before it (at most half the budget) to leave time
for the log and the export; the loss plot is drawn after the bundle, outside the budget. NEWRUN's ``log.json``
splits the time by stage (``update_time``: reading RUN, the retrace, saving the map, then the fine-tune's stages;
``startup_s``: the process's start before the call).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.cli.common import refuse_to_replace
from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.photons.albedo_reweight import albedo_only, reweight_albedo
from photon_fields.runtime.photons.photon_map import PhotonMap, read_header
from photon_fields.runtime.scene.light_rescale import scene_rescale
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.train.export.bundle import ExportResult, export_bundle, read_run_domain, write_run_domain
from photon_fields.train.fit.checkpoint import load_checkpoint
from photon_fields.train.fit.early_stop import DEFAULT_MIN_IMPROVEMENT, DEFAULT_PATIENCE, PlateauStop
from photon_fields.train.fit.fine_tune import fine_tune
from photon_fields.train.fit.loop import LOG_KEYS, FitResult
from photon_fields.train.fit.plots import plot_loss
from photon_fields.train.fit.presets import (
    PRESETS,
    UPDATE_BUDGET_S,
    UPDATE_LR_SHARE,
    UPDATE_MAX_STEPS,
    UPDATE_MIN_PHOTONS,
    UPDATE_OUTPUT_RESERVE_S,
    UPDATE_PHOTONS,
    UPDATE_TRACE_SHARE,
    UPDATE_VAL_EVERY,
)
from photon_fields.train.fit.schedule import naive_schedule
from photon_fields.train.fit.settings import FitSettings
from photon_fields.train.photons.tracing import light_fluxes, trace_photons

#: What an update writes into NEWRUN (what ``pfn-train all`` writes).
UPDATE_OUTPUTS = ("checkpoint.pt", "log.json", "loss.png", "domain.json", "map.npz", "field.pfn")
DEFAULT_MAX_BOUNCES = 16


@dataclass(frozen=True)
class RunRecord:
    """What an update needs from an earlier run folder (:func:`read_run`)."""

    path: Path
    scene_name: str | None
    settings: FitSettings
    fingerprint: str
    parts: dict[str, str] | None
    bmin: tuple[float, ...]
    bsize: tuple[float, ...]
    photons: int
    phases: tuple[float, ...]
    max_bounces: int
    map_seed: int
    steps: int
    lights: list[dict[str, Any]] | None = None
    """The run's lights as its scene file recorded them (``domain.json``'s ``scene_spec``), None for older runs."""
    light_channels: int = 1
    """The run's field's light channels (``FieldConfig.light_channels`` in ``log.json``'s ``field_config``)."""
    transfer: dict[str, Any] | None = None
    """The run's transfer function as its scene file recorded it (``domain.json``'s ``scene_spec``), or None."""

    def light_rescale(self, scene: Scene) -> np.ndarray | None:
        """The RGB factor (3,), or one per light (L, 3) for a field that keeps its lights apart, when ``scene`` differs
        from this run's scene only in its lights, by a rescale of their flux
        (:mod:`photon_fields.runtime.scene.light_rescale`): the run's field then renders ``scene`` exactly, rescaled,
        and an update is not needed. None otherwise."""
        return scene_rescale(self.parts, self.lights, scene.fingerprint_parts(), scene.light_identities(),
                             self.light_channels)


def _read_json(path: Path) -> dict[str, Any]:
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(str(path.parent), f"no {path.name}: not a run folder of pfn-train all or fit") from None
    except (OSError, ValueError) as exc:
        raise InputError(str(path), f"unreadable ({exc})") from None
    if not isinstance(doc, dict):
        raise InputError(str(path), "must hold a JSON object")
    return doc


def read_run(run: str | Path) -> RunRecord:
    """The settings, scene fingerprints, world box and map parameters of a finished run folder (module
    docstring); one-line errors naming RUN or the file."""

    path = Path(run)
    if not path.is_dir():
        raise InputError(str(path), "run folder not found" if not path.exists() else "is not a run folder")
    if not (path / "checkpoint.pt").is_file():
        raise InputError(str(path), "no checkpoint.pt: not a run folder of pfn-train all or fit")
    log = _read_json(path / "log.json")
    check_keys(log, LOG_KEYS, str(path / "log.json"), required=("scene_fingerprint", "settings", "photons",
                                                                 "phases", "status"))
    if log["status"] != "done":
        raise InputError(str(path / "log.json"), f"the run did not finish (status {log['status']!r})")
    settings = FitSettings.from_dict(log["settings"], f"{path / 'log.json'} settings")
    fingerprint = str(log["scene_fingerprint"])
    bmin, bsize, record = read_run_domain(path, fingerprint)
    photons, phases = int(log["photons"]), tuple(float(g) for g in log["phases"])
    max_bounces, map_seed = DEFAULT_MAX_BOUNCES, settings.seed
    parts = record.get("parts")
    if (path / "map.npz").is_file():
        header = read_header(path / "map.npz", expected_fingerprint=fingerprint)
        photons, phases = header.count, header.phases
        max_bounces = int(header.meta.get("max_bounces", DEFAULT_MAX_BOUNCES))
        map_seed = int(header.meta.get("seed", map_seed))
        parts = parts or header.scene_parts
    steps = int((log.get("totals") or {}).get("steps_done", settings.steps))
    lights = (record.get("spec") or {}).get("lights")
    channels = (log.get("field_config") or {}).get("light_channels", 1) if isinstance(log.get("field_config"),
                                                                                      dict) else 1
    transfer = (record.get("spec") or {}).get("transfer_function")
    return RunRecord(path, record.get("name"), settings, fingerprint, parts, tuple(bmin), tuple(bsize), photons,
                     phases, max_bounces, map_seed, steps, lights if isinstance(lights, list) else None,
                     channels if isinstance(channels, int) else 1, transfer if isinstance(transfer, dict) else None)


def check_update(record: RunRecord, scene: Scene, what: str = "--scene") -> None:
    """Refuse, in one line, an update of ``record``'s field to ``scene`` that cannot work: another volume or
    world box, or a scene with nothing to see (zero opacity everywhere, no light power reaching the volume)."""
    if not record.parts or "volume" not in record.parts:
        raise InputError(str(record.path), "records no per-part scene fingerprints (an older run): it cannot be "
                         "told whether NEW has the same volume; train NEW with pfn-train all")
    if scene.fingerprint_parts()["volume"] != record.parts["volume"]:
        raise InputError(what, f"'{scene.name}' has another volume than the run {str(record.path)!r} (data, dims "
                         "or spacing differ): an update changes only the transfer function and lights; train it "
                         "with pfn-train all")
    m = scene.medium()
    if not (np.allclose(m.bmin, record.bmin, rtol=0, atol=1e-9) and np.allclose(m.bsize, record.bsize, rtol=0,
                                                                                 atol=1e-9)):
        raise InputError(what, f"'{scene.name}' has another world box than the run {str(record.path)!r}")
    if not float(np.max(m.majorant)) > 0.0:
        raise InputError(what, f"'{scene.name}' leaves nothing visible: the transfer function's opacity is 0 "
                         "everywhere in the volume")
    flux, _ = light_fluxes(scene)
    if not float(flux.sum()) > 0.0:
        raise InputError(what, f"'{scene.name}' leaves nothing visible: no light power reaches the volume")


def check_budget(budget_s: float, max_steps: int) -> None:
    if isinstance(budget_s, bool) or not isinstance(budget_s, (int, float)) or not math.isfinite(budget_s) \
            or budget_s <= 0:
        raise InputError("--budget", f"must be a positive number of seconds, got {budget_s!r}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0:
        raise InputError("--max-steps", f"must be an integer >= 0, got {max_steps!r}")


def update_settings(old: FitSettings, photons: int, seed: int, lr_share: float = UPDATE_LR_SHARE) -> FitSettings:
    """The fine-tune's settings: the old run's (preset, batch, K, sampling, loss, ...) at its final radius
    throughout, ``lr_share`` (default :data:`photon_fields.train.fit.presets.UPDATE_LR_SHARE`) of the preset's
    learning rate, validation every :data:`photon_fields.train.fit.presets.UPDATE_VAL_EVERY` steps."""
    final = old.resolve_schedule(photons).radii_percent[-1]
    return replace(old, lr=PRESETS[old.preset].lr * lr_share, schedule=naive_schedule(final),
                   schedule_kind="naive", seed=seed, val_every=UPDATE_VAL_EVERY, average=0.0)


@dataclass
class UpdateResult:
    out: Path
    fit: FitResult
    bundle: ExportResult
    trace_s: float
    wall_s: float
    time_split: dict[str, float]
    """Seconds by stage: ``log.json``'s ``update_time`` (``read_run_s``: RUN's files and checks; ``trace_s``: the new
    map, retraced or reweighted;
    ``save_map_s``: ``map.npz`` and ``domain.json``; the fine-tune's stages to ``fine_tune_s``), then
    ``outputs_s`` (the loss plot and the last log write), ``export_s`` and ``wall_s`` (the call, end to end)."""
    map_from: str = "retraced"
    """How the new map was made: "retraced", or "reweighted" (RUN's map, for an edit of the albedo alone,
    :func:`reweighted_map`)."""


def reweighted_map(record: RunRecord, scene: Scene, photons: int, seed: int) -> PhotonMap | None:
    """RUN's map as ``scene``'s when the edit changes the transfer function's albedo and nothing else: every record
    reweighted exactly, its paths thinned to about ``photons`` records
    (:mod:`photon_fields.runtime.photons.albedo_reweight`); None when that cannot be (another edit, a map without
    its path records or with fewer lights apart, a channel lit that was dark), and the update retraces."""
    path = record.path / "map.npz"
    if record.transfer is None or not path.is_file() or record.lights != scene.light_identities() \
            or _without_albedo(record.transfer) != _without_albedo(scene.tf.to_dict()):
        return None
    try:
        before = replace(scene, tf=TransferFunction.from_dict(record.transfer, what="RUN transfer_function",
                                                                 volume=scene.volume), _cache={})
    except InputError:
        return None
    if before.fingerprint() != record.fingerprint or not albedo_only(before.medium(), scene.medium()):
        return None
    pmap = PhotonMap.load(path, expected_fingerprint=record.fingerprint)
    if record.light_channels > 1 and pmap.light_count != record.light_channels:
        return None  # a field of light channels needs each photon's light
    keep = min(1.0, photons / max(len(pmap), 1))
    return reweight_albedo(pmap, before.medium(), scene.medium(), scene, keep=keep, seed=seed)


def _without_albedo(spec: Any) -> Any:
    """A transfer function's dict without its albedo entries (what an albedo-only edit leaves equal)."""
    if isinstance(spec, dict):
        return {k: _without_albedo(v) for k, v in spec.items() if k not in ("albedo", "name")}
    if isinstance(spec, list):
        return [_without_albedo(v) for v in spec]
    return spec


def update_run(run: str | Path, scene: Scene, out: str | Path, *, budget_s: float = UPDATE_BUDGET_S,
               max_steps: int = UPDATE_MAX_STEPS, seed: int | None = None, photons: int | None = None,
               force: bool = False, scene_source: str | None = None, tables_dtype: str = "float32",
               min_improvement: float = DEFAULT_MIN_IMPROVEMENT, patience: int = DEFAULT_PATIENCE,
               lr_share: float = UPDATE_LR_SHARE,
               progress: bool = True, on_progress: Callable[[str, int, int], None] | None = None,
               started: float | None = None,
               on_bundle: Callable[[ExportResult], None] | None = None, reweight: bool = True) -> UpdateResult:
    """Update RUN's field to ``scene`` into the run folder ``out`` (module docstring). ``seed`` (default: RUN's
    map's) seeds the retrace and the fine-tune; ``photons`` (default: RUN's map's count, at most
    :data:`photon_fields.train.fit.presets.UPDATE_PHOTONS`) the new map's size.
    ``on_progress(stage, done, total)``: stages ``trace``, ``fit``, ``export``. Bad input: one-line
    :class:`InputError`, raised before anything is written. ``started``: the ``time.perf_counter()`` the budget
    counts from, if earlier than the call (``pfn-train update`` passes its process's start, so that ``--budget``
    bounds the command's wall time, its imports included: the viewer's retrain runs it as a process).
    ``on_bundle(export)`` is called once the bundle is written, before the loss plot (``pfn-train update`` marks its
    progress file done there: the viewer swaps the field in while the plot is drawn). ``reweight`` False: retrace
    even for an edit of the albedo alone (:func:`reweighted_map`; for comparisons)."""
    t_call = time.perf_counter()
    t0 = t_call if started is None else min(float(started), t_call)
    check_budget(budget_s, max_steps)
    if isinstance(lr_share, bool) or not isinstance(lr_share, (int, float)) or not 0 < lr_share <= 1:
        raise InputError("lr share", f"must be a number in (0, 1], got {lr_share!r}")
    src, dest = Path(run), Path(out)
    if dest.exists() and src.exists() and dest.resolve() == src.resolve():
        raise InputError("--out", f"{str(dest)!r} is RUN itself; an update writes a new run folder and leaves RUN "
                         "as it is")
    record = read_run(src)
    check_update(record, scene)
    seed = record.map_seed if seed is None else int(seed)
    photons = min(record.photons, UPDATE_PHOTONS) if photons is None else int(photons)
    settings = update_settings(record.settings, photons, seed, lr_share)
    if dest.exists() and not dest.is_dir():
        raise InputError("--out", f"{str(dest)!r} is a file; --out names a run folder")
    refuse_to_replace([dest / name for name in UPDATE_OUTPUTS], force, f"an earlier run in {str(dest)!r}")
    model, _ = load_checkpoint(src / "checkpoint.pt", expected_fingerprint=record.fingerprint)
    try:
        dest.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError("--out", f"cannot create the folder {str(dest)!r}: {exc.strerror or exc}") from None
    read_s = time.perf_counter() - t_call

    def stage(name: str) -> Callable[[int, int], None] | None:
        return None if on_progress is None else (lambda done, total: on_progress(name, done, total))

    t1 = time.perf_counter()
    pmap = reweighted_map(record, scene, photons, seed) if reweight else None
    map_from = "reweighted" if pmap is not None else "retraced"
    if pmap is None:
        trace_deadline = t1 + UPDATE_TRACE_SHARE * max(t0 + float(budget_s) - t1, 0.0)
        pmap = trace_photons(scene, photons, phases=record.phases, max_bounces=record.max_bounces, seed=seed,
                             progress=progress, on_progress=stage("trace"), deadline=trace_deadline,
                             min_photons=min(photons, UPDATE_MIN_PHOTONS))
    t2 = time.perf_counter()
    pmap.save(dest / "map.npz")
    trace_s = time.perf_counter() - t_call
    write_run_domain(dest, scene, scene_source)
    t_fit = time.perf_counter()
    spent = {"budget_s": float(budget_s), "startup_s": t_call - t0, "read_run_s": read_s,
             "trace_s": t2 - t1, "save_map_s": t_fit - t2}
    warm = {"run": str(src), "scene": record.scene_name, "scene_fingerprint": record.fingerprint,
            "steps": record.steps, "map_seed": record.map_seed, "map": map_from}
    deadline = t0 + float(budget_s) - min(UPDATE_OUTPUT_RESERVE_S, 0.5 * float(budget_s))
    result = fine_tune(model, scene, pmap, dest, settings, max_steps=max_steps, deadline=deadline,
                       stop=PlateauStop(min_improvement, patience), warm_start_from=warm, progress=progress,
                       on_progress=stage("fit"), spent=spent, plot=False)
    t3 = time.perf_counter()
    if on_progress is not None:
        on_progress("export", 0, 1)
    bundle = export_bundle(dest, dest / "field.pfn", tables_dtype=tables_dtype, force=True)
    t4 = time.perf_counter()
    if on_bundle is not None:
        on_bundle(bundle)
    plot_loss(result.log, dest / "loss.png")
    wall = time.perf_counter() - t0
    logged = result.log["update_time"]  # up to the log's writing; then the export, and the plot
    split = {**logged, "outputs_s": t3 - t_fit - logged["fine_tune_s"], "export_s": t4 - t3,
             "bundle_s": t4 - t0, "plot_s": time.perf_counter() - t4, "wall_s": wall}
    return UpdateResult(dest, result, bundle, trace_s, wall, split, map_from)
