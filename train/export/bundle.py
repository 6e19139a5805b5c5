"""Export a trained photon field as a bundle (``NAME.pfn/``, format :mod:`photon_fields.models_spec.bundle`).

``pfn-train export RUN_DIR [--out RUN_DIR/field.pfn] [--tables-dtype float32|float16] [--force]`` and the last
step of ``pfn-train all`` call :func:`export_bundle`:

1. load ``RUN_DIR/checkpoint.pt`` (:func:`train.fit.loop.load_checkpoint`) and the run's domain box: the world
   box ``[bmin, bmin + bsize]`` training normalized positions with (``normalize_position``, Sec. 3.1),
   from ``RUN_DIR/domain.json`` (written by ``pfn-train fit`` / ``all``, :func:`write_run_domain`) or from a
   scene given with ``--scene`` (its fingerprint must equal the checkpoint's). The same source gives the
   manifest's ``scene`` record (name, per-part fingerprints, the scene file that rebuilds it); a version 1
   ``domain.json`` has only the name. ``domain.json``, ``log.json`` and the checkpoint's metadata refuse
   unknown keys like every JSON input;
2. ``field.onnx``: the MLP alone (Sec. 3.4, Fig. 5), built directly with ``onnx.helper`` from the
   weight matrices (:func:`mlp_onnx`), not with ``torch.onnx.export``. The network is bias-free
   Linear/ReLU, i.e. ``MatMul, Relu, ..., MatMul``: building it by hand is a dozen lines, gives one
   self-contained file (torch 2.13's default dynamo exporter writes weights to a separate ``.onnx.data``
   file and needs onnxscript), is byte-for-byte deterministic (no exporter version strings, no generated
   node names, no timestamps) and takes milliseconds. That it computes the torch model's function is what
   the export verification below and tests/runtime/field/test_bundle.py check;
3. ``tables.npz``: the two flat hash tables, float32 or float16 (half the size; the runtime widens them
   back, see :mod:`runtime.field.field`), written as a zip with fixed timestamps so the same checkpoint gives
   the same bytes (``numpy.savez`` stamps the current time);
4. ``manifest.json`` (:func:`photon_fields.models_spec.bundle.build_manifest`): architecture, domain, input layout,
   scene fingerprint, training summary (from the checkpoint, preset and batch from ``log.json``), sha256
   and size of the two files. No creation time: exports of one checkpoint are byte-identical;
5. verification: the staged bundle is loaded with the runtime loader (:meth:`runtime.field.field.PhotonField.load`,
   all of its checks) and queried on 4096 random and edge inputs against the torch model: max abs
   difference on L' must be <= :data:`VERIFY_TOL` (float16 tables: against the torch model evaluated with
   the same rounded tables);
6. atomic placement: everything is written into a hidden staging directory beside the target
   (``.NAME.pfn.<random>.tmp``) and renamed into place, so an interrupted export leaves no half bundle and
   any previous bundle intact. An existing bundle is only replaced with ``force`` (``pfn-train all``
   always replaces its own ``RUN/field.pfn``): the old one is first renamed aside
   (``.NAME.pfn.<random>.old``), the new one renamed in, the old one deleted. A crash between those two
   renames (a few microseconds) leaves the old bundle under the ``.old`` name, never a mix. A directory
   that is not a bundle is never replaced.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from photon_fields.models_spec.bundle import (
    BATCH_AXIS,
    BUNDLE_FILES,
    BUNDLE_SUFFIX,
    MANIFEST_FILE,
    ONNX_FILE,
    ONNX_INPUT,
    ONNX_IR_VERSION,
    ONNX_OPSET,
    ONNX_OUTPUT,
    SURFACE_ARRAY,
    SURFACE_DTYPE,
    TABLE_ARRAYS,
    TABLE_DTYPES,
    TABLES_FILE,
    BundleError,
    build_manifest,
    file_digest,
    manifest_text,
    scene_record,
    training_summary,
    validate_manifest,
    validate_scene_record,
)
from photon_fields.models_spec.encoding import direction_input, normalize_position
from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_write_text, fsync_dir
from photon_fields.runtime.scene.scene import Scene
from photon_fields.train.field.network import TorchPhotonField as TorchField
from photon_fields.train.fit.checkpoint import load_checkpoint
from photon_fields.train.fit.loop import LOG_KEYS

RUN_DOMAIN_FILE = "domain.json"
RUN_DOMAIN_FORMAT = "photon-fields/run-domain"
#: Version 2 added ``scene_parts`` and ``scene_spec``; version 1 files are still read (both unknown).
RUN_DOMAIN_VERSION = 2
_RUN_DOMAIN_KEYS = {1: ("format", "version", "scene", "scene_source", "scene_fingerprint", "bmin", "bsize")}
_RUN_DOMAIN_KEYS[2] = (*_RUN_DOMAIN_KEYS[1], "scene_parts", "scene_spec")
CHECKPOINT_FILE = "checkpoint.pt"
DEFAULT_BUNDLE_NAME = "field" + BUNDLE_SUFFIX
#: Max abs difference on L' between the exported bundle (runtime) and the torch model, checked at export.
VERIFY_TOL = 1e-5
VERIFY_POINTS = 4096
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # the earliest zip timestamp: fixed, so the archive bytes are reproducible


# ----------------------------------------------------------------------------------------------------
# The run's domain box
# ----------------------------------------------------------------------------------------------------


def write_run_domain(run_dir: str | Path, scene: Scene, source: str | None = None) -> Path:
    """Record the scene's world box, fingerprints and description in ``RUN_DIR/domain.json`` (for a later
    export: the bundle carries the scene's part fingerprints and the scene file that rebuilds it)."""
    m = scene.medium()
    doc = {"format": RUN_DOMAIN_FORMAT, "version": RUN_DOMAIN_VERSION, "scene": scene.name, "scene_source": source,
           "scene_fingerprint": scene.fingerprint(), "bmin": [float(v) for v in m.bmin],
           "bsize": [float(v) for v in m.bsize], "scene_parts": scene.fingerprint_parts(),
           "scene_spec": scene.spec()}
    path = Path(run_dir) / RUN_DOMAIN_FILE
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path


def _run_domain(run_dir: Path, fingerprint: str, scene: Scene | None) -> tuple[list[float], list[float],
                                                                               dict[str, Any]]:
    """The world box and the manifest's ``scene`` record, from ``scene`` (checked against the checkpoint's
    fingerprint) or from the run's ``domain.json`` (version 1 has no parts or spec: they stay unknown)."""
    if scene is not None:
        if scene.fingerprint() != fingerprint:
            raise InputError("--scene", f"'{scene.name}' is not the scene the checkpoint was trained for "
                             "(fingerprint mismatch: volume, transfer function or lights differ)")
        m = scene.medium()
        return ([float(v) for v in m.bmin], [float(v) for v in m.bsize],
                scene_record(scene.name, scene.fingerprint_parts(), scene.spec()))
    path = run_dir / RUN_DOMAIN_FILE
    if not path.is_file():
        raise InputError(str(run_dir), f"no {RUN_DOMAIN_FILE} (the world box training normalized positions "
                         "with); pass --scene SCENE")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(str(path), f"unreadable: {exc}; pass --scene SCENE") from None
    if not isinstance(doc, dict) or doc.get("format") != RUN_DOMAIN_FORMAT:
        raise InputError(str(path), f"not a run-domain file (format {RUN_DOMAIN_FORMAT!r}); pass --scene SCENE")
    version = doc.get("version")
    if version not in _RUN_DOMAIN_KEYS:
        raise InputError(str(path), f"version {version!r} is not supported (this build reads versions "
                         f"{', '.join(map(str, _RUN_DOMAIN_KEYS))}); pass --scene SCENE")
    check_keys(doc, _RUN_DOMAIN_KEYS[version], str(path),
               required=("format", "version", "scene_fingerprint", "bmin", "bsize"))
    try:
        bmin = [float(v) for v in doc["bmin"]]
        bsize = [float(v) for v in doc["bsize"]]
        if len(bmin) != 3 or len(bsize) != 3 or not all(np.isfinite(bmin + bsize)) or min(bsize) <= 0:
            raise ValueError("bmin and bsize must be 3 finite numbers, bsize > 0")
    except (ValueError, TypeError) as exc:
        raise InputError(str(path), f"unreadable: {exc}; pass --scene SCENE") from None
    if doc.get("scene_fingerprint") != fingerprint:
        raise InputError(str(path), "belongs to another scene than the checkpoint (fingerprint mismatch)")
    name = doc.get("scene")
    record = {"name": name if isinstance(name, str) else None, "parts": doc.get("scene_parts"),
              "spec": doc.get("scene_spec")}
    try:
        validate_scene_record(record)
    except BundleError as err:
        raise InputError(f"{path} {err.what}", err.problem) from None
    return bmin, bsize, record


def read_run_domain(run_dir: str | Path, fingerprint: str) -> tuple[list[float], list[float], dict[str, Any]]:
    """The world box and scene record (name, per-part fingerprints, spec) of ``RUN_DIR/domain.json``, which must
    belong to the scene of ``fingerprint`` (what ``pfn-train update`` reads of an earlier run)."""
    return _run_domain(Path(run_dir), fingerprint, None)


# ----------------------------------------------------------------------------------------------------
# The two payload files
# ----------------------------------------------------------------------------------------------------


def mlp_weights(model: TorchField) -> list[np.ndarray]:
    """The MLP's weight matrices as float32 (out, in) arrays, input layer first (bias-free Linear layers)."""
    weights = []
    for layer in model.mlp:
        if isinstance(layer, torch.nn.Linear):
            if layer.bias is not None:
                raise ValueError("the photon field's MLP has no biases (tcnn's FullyFusedMLP)")
            weights.append(layer.weight.detach().to(torch.float32).cpu().numpy().copy())
        elif not isinstance(layer, torch.nn.ReLU):
            raise ValueError(f"unexpected MLP layer {type(layer).__name__}")
    return weights


def mlp_onnx(weights: list[np.ndarray]) -> bytes:
    """Serialized ONNX model of ``x -> W_k (... relu(W_1 relu(W_0 x)))`` (bias-free ReLU MLP, no output
    activation): input ``features`` (batch, in), output ``encoded_radiance`` (batch, out)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    if not weights:
        raise ValueError("an MLP needs at least one layer")
    nodes, inits = [], []
    current = ONNX_INPUT
    for i, w in enumerate(weights):
        if i and w.shape[1] != weights[i - 1].shape[0]:
            raise ValueError(f"layer {i} takes {w.shape[1]} inputs, layer {i - 1} gives {weights[i - 1].shape[0]}")
        name = f"layer{i}.weight_t"
        # MatMul(x, W^T): stored transposed (in, out), C-contiguous: what MatMul reads.
        inits.append(numpy_helper.from_array(np.ascontiguousarray(w.T, dtype=np.float32), name))
        last = i == len(weights) - 1
        pre = ONNX_OUTPUT if last else f"layer{i}.linear"
        nodes.append(helper.make_node("MatMul", [current, name], [pre], name=f"layer{i}.matmul"))
        if not last:
            nodes.append(helper.make_node("Relu", [pre], [f"layer{i}.relu"], name=f"layer{i}.relu"))
            current = f"layer{i}.relu"
    graph = helper.make_graph(
        nodes, "photon_field_mlp",
        [helper.make_tensor_value_info(ONNX_INPUT, TensorProto.FLOAT, [BATCH_AXIS, int(weights[0].shape[1])])],
        [helper.make_tensor_value_info(ONNX_OUTPUT, TensorProto.FLOAT, [BATCH_AXIS, int(weights[-1].shape[0])])],
        inits)
    graph.doc_string = ("Photon field MLP (Sec. 3.4): [hash(position), hash(direction), g] -> L' (Eq. 6); "
                        "see models_spec/bundle.py")
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", ONNX_OPSET)],
                              producer_name="photon-fields", producer_version="1")
    model.ir_version = ONNX_IR_VERSION
    onnx.checker.check_model(model, full_check=True)
    return model.SerializeToString()


def write_tables_npz(path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    """An .npz that ``np.load(allow_pickle=False)`` reads, with fixed zip timestamps (reproducible bytes).
    Stored uncompressed: float tables barely compress, and loading stays a plain read."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME)
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(arr), allow_pickle=False)


def _tables(model: TorchField, dtype: str) -> dict[str, np.ndarray]:
    out = {}
    for name, enc in (("position", model.position), ("direction", model.direction)):
        t = enc.table.detach().cpu().numpy()
        with np.errstate(over="ignore"):
            cast = t.astype(dtype)
        if not np.all(np.isfinite(cast)):
            raise InputError("--tables-dtype", f"the {name} table has values beyond {dtype}'s range "
                             f"(max |v| = {float(np.abs(t).max()):.3g}); export with float32")
        out[name] = cast
    if model.cfg.surface is not None:  # the surface input's grid, int8 whatever the tables' dtype
        out[SURFACE_ARRAY] = model.surface.detach().cpu().numpy().astype(SURFACE_DTYPE)
    return out


# ----------------------------------------------------------------------------------------------------
# Verification
# ----------------------------------------------------------------------------------------------------


def verification_inputs(bmin: np.ndarray, bsize: np.ndarray, phases: tuple[float, ...], n: int = VERIFY_POINTS,
                        seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World positions (box corners and faces included), unit directions (poles and the azimuth seam
    included) and g (G, -1, 0, 1 and values between) for checking a bundle against its torch model."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 3))
    u[:8] = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)  # box corners
    x = bmin + u * bsize
    d = rng.standard_normal((n, 3))
    d[:6] = [[0, 0, 1], [0, 0, -1], [-1, 0.0, 0], [-1, -0.0, 0], [1, 0, 0], [0, 1, 0]]  # poles, seam
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    gs = np.array(sorted({*phases, -1.0, 0.0, 1.0, -0.35, 0.35}))
    g = np.concatenate([gs, rng.uniform(-1, 1, n - gs.size)])[:n]
    return x, d, g


@torch.no_grad()
def torch_encoded(model: TorchField, x: np.ndarray, d: np.ndarray, g: np.ndarray, bmin: np.ndarray,
                  bsize: np.ndarray) -> np.ndarray:
    """The torch model's L' for world inputs (the reference the runtime must reproduce)."""
    pos = torch.from_numpy(normalize_position(x, bmin, bsize))
    dirs = torch.from_numpy(direction_input(d))
    gt = torch.from_numpy(np.asarray(g, np.float32).reshape(-1, 1))
    return model(pos, dirs, gt).numpy()


def _verify(staging: Path, model: TorchField, tables: dict[str, np.ndarray], bmin: np.ndarray,
            bsize: np.ndarray) -> float:
    from photon_fields.runtime.field.field import PhotonField

    loaded = PhotonField.load(staging)
    x, d, g = verification_inputs(bmin, bsize, model.cfg.phases)
    ref_model = model
    if any(tables[name].dtype != np.float32 for name in TABLE_ARRAYS):
        # float16 tables: the runtime computes the function of the rounded tables; compare with exactly that.
        import copy

        ref_model = copy.deepcopy(model)
        with torch.no_grad():
            ref_model.position.table.copy_(torch.from_numpy(tables["position"].astype(np.float32)))
            ref_model.direction.table.copy_(torch.from_numpy(tables["direction"].astype(np.float32)))
    want = torch_encoded(ref_model, x, d, g, bmin, bsize)
    got = loaded.query_encoded(x, d, g)
    diff = float(np.max(np.abs(got.astype(np.float64) - want))) if len(x) else 0.0
    if not diff <= VERIFY_TOL:
        raise InputError(str(staging), f"verification failed: the bundle's output differs from the torch model by "
                         f"{diff:.3g} on L' (tolerance {VERIFY_TOL:g})")
    return diff


# ----------------------------------------------------------------------------------------------------
# Export
# ----------------------------------------------------------------------------------------------------


@dataclass
class ExportResult:
    path: Path
    manifest: dict[str, Any]
    verify_max_abs_diff: float | None
    seconds: float
    files: dict[str, int] = field(default_factory=dict)  # name -> bytes


def _read_log(run_dir: Path, fingerprint: str) -> dict[str, Any]:
    """The run's ``log.json`` if it belongs to the checkpoint's scene (only preset and batch come from it;
    a run folder without one exports without them). Unreadable, or with keys ``pfn-train fit`` does not
    write, or with a preset / batch of the wrong type: refused in one line, not silently dropped."""
    path = run_dir / "log.json"
    if not path.exists():
        return {}
    try:
        log = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise InputError(str(path), f"unreadable run log ({exc}); fix or remove it to export without its "
                         "preset and batch") from None
    if not isinstance(log, dict):
        raise InputError(str(path), "a run log must be a JSON object")
    check_keys(log, LOG_KEYS, str(path))
    if log.get("scene_fingerprint") != fingerprint:
        return {}
    settings = log.get("settings")
    if settings is not None:
        if not isinstance(settings, dict):
            raise InputError(f"{path} settings", "must be an object")
        preset, batch = settings.get("preset"), settings.get("batch")
        if preset is not None and not isinstance(preset, str):
            raise InputError(f"{path} settings preset", f"must be a preset name, got {preset!r}")
        if batch is not None and (isinstance(batch, bool) or not isinstance(batch, int) or batch < 1):
            raise InputError(f"{path} settings batch", f"must be a positive integer, got {batch!r}")
    return log


def _check_out(out: Path, force: bool) -> None:
    if out.suffix != BUNDLE_SUFFIX:
        raise InputError("--out", f"a bundle is a directory named NAME{BUNDLE_SUFFIX}, got {str(out)!r}")
    if out.exists() or out.is_symlink():
        if not out.is_dir() or out.is_symlink():
            raise InputError("--out", f"{str(out)!r} exists and is not a bundle directory; will not replace it")
        foreign = sorted(p.name for p in out.iterdir() if p.name not in BUNDLE_FILES)
        if foreign:
            raise InputError("--out", f"{str(out)!r} exists and is not a bundle (it holds {foreign[:3]}); "
                             "will not replace it")
        if not force:
            raise InputError("--out", f"{str(out)!r} exists; pass --force to replace it")


def export_bundle(run_dir: str | Path, out: str | Path | None = None, *, scene: Scene | None = None,
                  tables_dtype: str = "float32", force: bool = False, verify: bool = True) -> ExportResult:
    """Write the bundle of ``run_dir``'s checkpoint to ``out`` (default ``run_dir/field.pfn``); see the module
    docstring. One-line InputError for bad input; the previous bundle at ``out`` survives any failure."""
    t0 = time.perf_counter()
    run = Path(run_dir)
    if not run.is_dir():
        raise InputError(str(run), "run folder not found" if not run.exists() else "is not a folder (a run folder "
                         "from pfn-train fit)")
    ckpt = run / CHECKPOINT_FILE
    if not ckpt.is_file():
        raise InputError(str(run), f"no {CHECKPOINT_FILE} in the run folder (run pfn-train fit first)")
    if tables_dtype not in TABLE_DTYPES:
        raise InputError("--tables-dtype", f"must be one of {', '.join(TABLE_DTYPES)}, got {tables_dtype!r}")
    dest = Path(out) if out is not None else run / DEFAULT_BUNDLE_NAME
    _check_out(dest, force)
    model, data = load_checkpoint(ckpt)
    model.eval()
    fingerprint = str(data.get("scene_fingerprint", ""))
    bmin, bsize, scene_rec = _run_domain(run, fingerprint, scene)
    log = _read_log(run, fingerprint)
    summary = data.get("summary") or {}
    settings = log.get("settings") or {}
    training = training_summary(preset=settings.get("preset"), steps=int(data.get("step", 0)),
                                batch=settings.get("batch"), final_loss=summary.get("final_loss"),
                                validation=summary.get("final_validation"), wall_s=summary.get("wall_s"))
    onnx_bytes = mlp_onnx(mlp_weights(model))
    tables = _tables(model, tables_dtype)
    if not dest.parent.is_dir():  # only now: a refused export creates nothing
        try:
            dest.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InputError("--out", f"cannot create the folder {str(dest.parent)!r}: {exc.strerror or exc}") from None

    staging = dest.with_name(f".{dest.name}.{secrets.token_hex(4)}.tmp")
    staging.mkdir()
    try:
        (staging / ONNX_FILE).write_bytes(onnx_bytes)
        write_tables_npz(staging / TABLES_FILE, tables)
        files = {}
        for name in (ONNX_FILE, TABLES_FILE):
            digest, size = file_digest(staging / name)
            files[name] = {"sha256": digest, "bytes": size}
        manifest = build_manifest(model.cfg, bmin=bmin, bsize=bsize, scene_fingerprint=fingerprint,
                                  training=training, tables_dtype=tables_dtype, files=files, scene=scene_rec)
        validate_manifest(manifest)  # the exporter holds itself to the reader's rules
        (staging / MANIFEST_FILE).write_text(manifest_text(manifest))
        for name in BUNDLE_FILES:
            fd = os.open(staging / name, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        diff = _verify(staging, model, tables, np.asarray(bmin), np.asarray(bsize)) if verify else None
        _place(staging, dest)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return ExportResult(dest, manifest, diff, time.perf_counter() - t0,
                        {n: (dest / n).stat().st_size for n in BUNDLE_FILES})


def _place(staging: Path, dest: Path) -> None:
    """Rename the finished staging directory to ``dest`` (replacing a previous bundle; module docstring)."""
    old = None
    if dest.exists():
        old = dest.with_name(f".{dest.name}.{secrets.token_hex(4)}.old")
        os.rename(dest, old)
    try:
        os.rename(staging, dest)
    except BaseException:
        if old is not None:
            os.rename(old, dest)  # put the previous bundle back
        raise
    fsync_dir(dest.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


__all__ = ["export_bundle", "write_run_domain", "read_run_domain", "mlp_onnx", "mlp_weights", "write_tables_npz",
           "ExportResult", "verification_inputs", "torch_encoded"]
