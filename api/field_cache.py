"""Photon fields (and photon maps) trained on first use and kept in a cache folder, keyed by the scene.

``photon_fields.render(..., method="field")`` needs a field trained for the scene's light distribution: its
volume, transfer function and lights, which :meth:`photon_fields.runtime.scene.scene.Scene.fingerprint` hashes
(camera and g do not count: one field serves every view and any g). The first call trains one with the trainer
itself, run as ``python -m photon_fields.train.cli.train all`` in a child process (as the viewer's retraining
does: the runtime never imports torch), and later calls with the same scene and training settings load it.
``method="photonmap"`` does the same with ``pfn-train trace`` and a photon map. ``method="pvrt"`` caches a PVRT
transfer (:func:`cached_transfer`): precomputed in this process (the runtime's own, no torch), keyed by the volume,
transfer function and g it depends on, not the lights it is relit with.

Cache folder: ``cache`` if given, else ``$PFN_CACHE``, else ``~/.cache/photon-fields``. Entry
``fields/<key>/`` (``<key>``: a hash of the scene fingerprint, the kind and the training settings) holds
``scene.json`` (the scene file handed to the trainer), ``volume.npy`` (an in-memory volume, normalized, read back
with window [0, 1] so that its fingerprint is unchanged), ``train.log`` and the trainer's outputs (``run/field.pfn``
or ``map.npz``), ``entry.json`` (what it was made for: kind, seed, settings, the scene's per-part fingerprints and
lights) and, last, ``complete`` (written when the trainer succeeded): an entry without it (an interrupted or failed
training) is trained again. Two processes training the same entry at once are not guarded against.

A scene whose lights are an entry's with their flux rescaled (a light's power or colour: the same volume, transfer
function and light places, :mod:`photon_fields.runtime.scene.light_rescale`) uses that entry instead of training:
its field, or map, renders the scene exactly, rescaled at load. Entries made before ``entry.json`` are found only by
their own scene.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.scene.light_rescale import scene_rescale
from photon_fields.runtime.scene.scene import Scene

#: An entry's record of what it was made for (module docstring).
ENTRY_FILE = "entry.json"
#: The trainer, as this interpreter runs it.
TRAINER = (sys.executable, "-m", "photon_fields.train.cli.train")
#: Training settings (``training=``): a preset name, or these keys, each a ``pfn-train all`` option.
TRAINING_KEYS = ("preset", "photons", "steps", "batch", "k", "threads")
DEFAULT_TRAINING = {"preset": "cpu", "photons": "4M"}
#: Transfer settings of ``method="pvrt"`` (``pfn-train pvrt`` options, by keyword of ``precompute_transfer``).
PVRT_KEYS = ("basis", "order", "grid", "paths", "exitance_order", "clusters", "bases")
#: Photon-map settings of ``method="photonmap"`` (``pfn-train trace`` options).
TRACE_KEYS = ("photons", "threads")


def cache_root(cache: str | os.PathLike[str] | None = None) -> Path:
    """The cache folder (module docstring)."""
    if cache is not None:
        return Path(cache).expanduser()
    env = os.environ.get("PFN_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "photon-fields"


def training_settings(training: str | dict[str, Any] | None, kind: str) -> dict[str, Any]:
    """``training=`` checked: a preset name or a dict of :data:`TRAINING_KEYS` (:data:`TRACE_KEYS` for a
    photon map), merged over the defaults."""
    keys = TRAINING_KEYS if kind == "field" else PVRT_KEYS if kind == "pvrt" else TRACE_KEYS
    if training is None:
        given: dict[str, Any] = {}
    elif isinstance(training, str):
        given = {"preset": training}
    elif isinstance(training, dict):
        given = dict(training)
    else:
        raise InputError("training", f"must be a preset name or a dict of {', '.join(keys)}, got {training!r}")
    if kind != "field":
        given.pop("preset", None)
    check_keys(given, keys, "training")
    defaults = {k: v for k, v in DEFAULT_TRAINING.items() if k in keys and kind != "pvrt"}
    return {**defaults, **given}


def cached_input(scene: Scene, kind: str, settings: dict[str, Any], seed: int, cache: Path) -> Path:
    """The bundle (``kind="field"``) or photon map (``"photonmap"``) for ``scene``: from the cache, else made
    now by the trainer (module docstring)."""
    what = f"method '{kind}'"
    key = hashlib.sha256(json.dumps({"scene": scene.fingerprint(), "kind": kind, "seed": int(seed),
                                     "settings": settings}, sort_keys=True).encode()).hexdigest()[:24]
    entry = cache / "fields" / key
    target = entry / ("run/field.pfn" if kind == "field" else "map.npz")
    if (entry / "complete").exists() and target.exists():
        return target
    relit = rescalable_entry(scene, kind, settings, seed, cache)
    if relit is not None:
        return relit
    if importlib.util.find_spec("torch") is None or importlib.util.find_spec("photon_fields.train") is None:
        raise InputError(what, "trains on first use, which needs the train extra (torch): "
                               "pip install 'photon-fields[train]'")
    try:
        entry.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(str(cache), f"cannot create the cache folder: {exc.strerror or exc}") from None
    scene_file = _write_scene(scene, entry)
    flags = [f"--{k}={v}" for k, v in settings.items()]
    if kind == "field":
        cmd = [*TRAINER, "all", str(scene_file), "--out", str(entry / "run"), "--seed", str(int(seed)), "--quiet",
               "--force", *flags]
    else:
        cmd = [*TRAINER, "trace", str(scene_file), "--out", str(target), "--seed", str(int(seed)), "--quiet",
               "--force", *flags]
    log = entry / "train.log"
    with open(log, "wb") as out:
        code = subprocess.run(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                              env={**os.environ, "PYTHONUNBUFFERED": "1"}).returncode
    if code != 0 or not target.exists():
        lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
        last = lines[-1] if lines else f"the trainer exited with status {code}"
        raise InputError(what, f"training failed: {last} (log: {log})")
    atomic_write_text(entry / ENTRY_FILE, json.dumps(_made_for(scene, kind, settings, seed)) + "\n")
    atomic_write_text(entry / "complete", " ".join(cmd) + "\n")
    return target


def _made_for(scene: Scene, kind: str, settings: dict[str, Any], seed: int) -> dict[str, Any]:
    return {"kind": kind, "seed": int(seed), "settings": settings, "parts": scene.fingerprint_parts(),
            "lights": scene.light_identities()}


def rescalable_entry(scene: Scene, kind: str, settings: dict[str, Any], seed: int, cache: Path) -> Path | None:
    """The field (or map) of a complete entry made with the same kind, seed and settings for ``scene``'s volume and
    transfer function and lights that ``scene``'s rescale (module docstring), or None."""
    wanted = _made_for(scene, kind, settings, seed)
    root = cache / "fields"
    for entry in sorted(root.iterdir()) if root.is_dir() else ():
        try:
            doc = json.loads((entry / ENTRY_FILE).read_text())
        except (OSError, ValueError):
            continue
        if not isinstance(doc, dict) or not (entry / "complete").exists() \
                or any(doc.get(k) != wanted[k] for k in ("kind", "seed", "settings")):
            continue
        target = entry / ("run/field.pfn" if kind == "field" else "map.npz")
        parts = doc.get("parts") if isinstance(doc.get("parts"), dict) else None
        if target.exists() and scene_rescale(parts, doc.get("lights"), wanted["parts"], wanted["lights"],
                                             _keeps_lights_apart(target, kind)) is not None:
            return target
    return None


def _keeps_lights_apart(target: Path, kind: str) -> int:
    """How many lights a cached field (its manifest's ``light_channels``) or map (a ``light`` array) keeps apart;
    1 when it does not, or cannot be read (the load that follows then says why)."""
    try:
        if kind == "field":
            channels = json.loads((target / "manifest.json").read_text())["field"].get("light_channels", 1)
            return channels if isinstance(channels, int) else 1
        from photon_fields.runtime.photons.photon_map import read_header

        return read_header(target).light_count
    except (OSError, ValueError, KeyError, TypeError, AttributeError, InputError):
        return 1


def cached_transfer(scene: Scene, settings: dict[str, Any], seed: int, cache: Path) -> Path:
    """The PVRT transfer (``transfer.pvrt``) for ``scene``'s volume, transfer function and g with ``settings``
    (:data:`PVRT_KEYS`): from the cache, else precomputed now (seconds to a minute on 2 cores) and written
    atomically, so an interrupted precomputation leaves no entry behind."""
    from photon_fields.runtime.pvrt import constants as c

    parts = scene.fingerprint_parts()
    # The defaults that fill what ``settings`` leaves out are part of the key: a transfer made under older defaults
    # (fewer basis lights, a coarser grid) is not what the same call gives now.
    defaults = {"order": c.DEFAULT_DSF_ORDER, "sh_order": c.DEFAULT_SH_ORDER, "grid": c.DEFAULT_GRID,
                "budget": c.TRANSFER_BUDGET_BYTES, "min_grid": c.MIN_AUTO_GRID, "paths": c.DEFAULT_PATHS_PER_BASIS,
                "exitance_tolerance": c.EXITANCE_TOLERANCE, "clusters": c.DEFAULT_CLUSTERS,
                "bases": c.DEFAULT_PCA_BASES, "kernel": c.KERNEL_C, "dense_tau": c.KERNEL_DENSE_TAU}
    key = hashlib.sha256(json.dumps({"volume": parts["volume"], "transfer_function": parts["transfer_function"],
                                     "g": float(scene.g), "kind": "pvrt", "seed": int(seed), "settings": settings,
                                     "defaults": defaults}, sort_keys=True).encode()).hexdigest()[:24]
    target = cache / "fields" / key / "transfer.pvrt"
    if target.exists():
        return target
    from photon_fields.runtime.pvrt.transfer import precompute_transfer, save_transfer

    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(str(cache), f"cannot create the cache folder: {exc.strerror or exc}") from None
    transfer = precompute_transfer(scene, seed=int(seed), progress=False, **settings)
    return save_transfer(transfer, target, force=True)


def _write_scene(scene: Scene, entry: Path) -> Path:
    """The scene as a file the trainer reads; an in-memory volume is saved beside it first."""
    spec = scene.spec()
    if spec is None:
        npy = entry / "volume.npy"
        with open(npy, "wb") as f:  # the entry is this call's own (a complete one returned above)
            np.save(f, np.ascontiguousarray(scene.volume.data, dtype=np.float32))
        spec = {"name": scene.name, "volume": {"path": str(npy.absolute()), "window": [0.0, 1.0],
                                               "spacing": list(scene.volume.spacing)},
                "transfer_function": scene.tf.to_dict(), "lights": [lt.to_dict() for lt in scene.lights],
                "camera": scene.camera.to_dict(), "phase": {"g": scene.g}}
    path = entry / "scene.json"
    atomic_write_text(path, json.dumps(spec, indent=1) + "\n")
    return path
