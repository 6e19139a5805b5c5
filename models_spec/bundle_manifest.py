"""Building and validating a bundle's manifest (the fields: :mod:`photon_fields.models_spec.bundle`):
:func:`build_manifest` and :func:`manifest_text` for the exporter, :func:`validate_manifest` and
:func:`parse_manifest_bytes` for the exporter (on what it wrote) and the runtime (on what it reads), and the
checks of the two other files against a manifest (:func:`check_table`, :func:`file_digest`).
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.bundle_layout import (
    BATCH_AXIS,
    BUNDLE_FORMAT,
    BUNDLE_VERSION,
    MANIFEST_FILE,
    MAX_MANIFEST_BYTES,
    ONNX_FILE,
    ONNX_INPUT,
    ONNX_OPSET,
    ONNX_OUTPUT,
    OUTPUT_ENCODING,
    READABLE_VERSIONS,
    SURFACE_ARRAY,
    SURFACE_DTYPE,
    TABLES_FILE,
    BundleError,
)
from photon_fields.models_spec.bundle_schema import MANIFEST_SCHEMA, manifest_schema
from photon_fields.models_spec.encoding import FieldConfig
from photon_fields.models_spec.fingerprint import FINGERPRINT_PARTS
from photon_fields.models_spec.hashgrid import HASH_PRIMES, HashGridConfig, level_specs, total_table_rows
from photon_fields.models_spec.schema_check import is_json_type, schema_check, show_json


def encoding_geometry(cfg: HashGridConfig) -> dict[str, Any]:
    """Derived per-level geometry of one hash grid, as the manifest lists it."""
    specs = level_specs(cfg)
    return {"table_rows": total_table_rows(cfg), "level_resolutions": [s.resolution for s in specs],
            "level_table_sizes": [s.table_size for s in specs], "level_hashed": [bool(s.hashed) for s in specs]}


def input_layout(cfg: FieldConfig) -> list[dict[str, Any]]:
    """Column ranges of the MLP input: position features, direction features, g (Sec. 3.4, Fig. 5), and the
    surface input's columns when the field has them."""
    p, d = cfg.position.output_dims, cfg.direction.output_dims
    g = p + d + cfg.phase_dims
    layout = [{"name": "position", "start": 0, "stop": p}, {"name": "direction", "start": p, "stop": p + d},
              {"name": "g", "start": p + d, "stop": g}]
    if cfg.surface_dims:
        layout.append({"name": "surface", "start": g, "stop": g + cfg.surface_dims})
    return layout


def table_shapes(cfg: FieldConfig) -> dict[str, tuple[int, ...]]:
    """Expected shape of each ``tables.npz`` array (the surface grid's only for a field with the surface input)."""
    shapes: dict[str, tuple[int, ...]] = {"position": (total_table_rows(cfg.position), cfg.position.features),
                                          "direction": (total_table_rows(cfg.direction), cfg.direction.features)}
    if cfg.surface is not None:
        shapes[SURFACE_ARRAY] = (*cfg.surface, 3)
    return shapes


def table_dtype(manifest: Manifest, name: str) -> np.dtype:
    """The dtype of ``tables.npz`` array ``name``: the surface grid's is int8 (:mod:`photon_fields.models_spec.
    surface`), the hash tables' the manifest's."""
    return np.dtype(SURFACE_DTYPE) if name == SURFACE_ARRAY else np.dtype(manifest.tables_dtype)


def _finite_or_none(v: Any) -> float | None:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def training_summary(*, preset: str | None, steps: int, batch: int | None, final_loss: Any,
                     validation: Mapping[str, Any] | None, wall_s: Any) -> dict[str, Any]:
    """The manifest's ``training`` entry (non-finite numbers become null: JSON has no NaN)."""
    val = None if validation is None else {str(k): _finite_or_none(v) for k, v in validation.items()
                                           if k != "step"}
    return {"preset": preset, "steps": int(steps), "batch": None if batch is None else int(batch),
            "final_loss": _finite_or_none(final_loss), "validation": val, "wall_s": _finite_or_none(wall_s)}


def scene_record(name: str | None = None, parts: Mapping[str, str] | None = None,
                 spec: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The manifest's ``scene`` entry (None: unknown)."""
    return {"name": name, "parts": None if parts is None else {p: str(parts[p]) for p in FINGERPRINT_PARTS},
            "spec": None if spec is None else json.loads(json.dumps(dict(spec)))}


def validate_scene_record(record: Any) -> None:
    """Check a ``scene`` entry on its own (:class:`BundleError` naming ``scene.<field>``)."""
    sub = MANIFEST_SCHEMA["properties"]["scene"]
    schema_check(record, sub, "scene", MANIFEST_SCHEMA)


def build_manifest(cfg: FieldConfig, *, bmin: Sequence[float], bsize: Sequence[float], scene_fingerprint: str,
                   training: Mapping[str, Any], tables_dtype: str, files: Mapping[str, Mapping[str, Any]],
                   scene: Mapping[str, Any] | None = None) -> dict:
    """The manifest dict for a field (``files``: ``{name: {"sha256", "bytes"}}`` of field.onnx and tables.npz;
    ``scene``: :func:`scene_record`, default all unknown)."""
    shapes = table_shapes(cfg)
    return {
        "format": BUNDLE_FORMAT, "version": BUNDLE_VERSION, "field": cfg.to_dict(),
        "hash_primes": [int(p) for p in HASH_PRIMES],
        "encodings": {"position": encoding_geometry(cfg.position), "direction": encoding_geometry(cfg.direction)},
        "domain": {"bmin": [float(v) for v in bmin], "bsize": [float(v) for v in bsize]},
        "inputs": {"width": cfg.input_dims, "layout": input_layout(cfg), "onnx_input": ONNX_INPUT,
                   "onnx_output": ONNX_OUTPUT, "batch_axis": BATCH_AXIS},
        "output": {"channels": cfg.output_dims, "encoding": OUTPUT_ENCODING},
        "tables": {"file": TABLES_FILE, "dtype": tables_dtype,
                   "arrays": {k: {"shape": list(v)} for k, v in shapes.items()}},
        "onnx": {"file": ONNX_FILE, "opset": ONNX_OPSET},
        "scene_fingerprint": scene_fingerprint,
        "scene": dict(scene) if scene is not None else scene_record(),
        "training": dict(training),
        "files": {name: {"sha256": str(files[name]["sha256"]), "bytes": int(files[name]["bytes"])}
                  for name in (ONNX_FILE, TABLES_FILE)},
    }


def manifest_text(manifest: Mapping[str, Any]) -> str:
    """Canonical manifest.json text (sorted keys would scatter related fields; insertion order is fixed
    by :func:`build_manifest`, so the text is deterministic)."""
    return json.dumps(manifest, indent=1, allow_nan=False) + "\n"


@dataclass(frozen=True)
class Manifest:
    """A validated manifest: the parsed pieces a runtime needs, and the raw dict."""

    config: FieldConfig
    bmin: np.ndarray  # float64 (3,)
    bsize: np.ndarray  # float64 (3,)
    scene_fingerprint: str
    tables_dtype: str
    files: dict[str, dict[str, Any]]
    training: dict[str, Any]
    raw: dict[str, Any]
    #: The ``scene`` entry (name, parts, spec; version 2), None for a version 1 manifest.
    scene: dict[str, Any] | None = None

    @property
    def scene_parts(self) -> dict[str, str] | None:
        return None if self.scene is None or self.scene["parts"] is None else dict(self.scene["parts"])

    @property
    def input_width(self) -> int:
        return self.config.input_dims


def validate_manifest(doc: Any, what: str = MANIFEST_FILE) -> Manifest:
    """Check a parsed manifest.json completely; raise :class:`BundleError` (``what``: the manifest's name
    in the message) for the first problem, else return the :class:`Manifest`."""
    if not isinstance(doc, dict):
        raise BundleError(what, f"must be a JSON object, got {type(doc).__name__}")
    # Format and version first, with their own words: a newer bundle deserves "update", not a schema dump.
    fmt = doc.get("format")
    if fmt != BUNDLE_FORMAT:
        raise BundleError(what, f"not a photon-field bundle manifest (format {show_json(fmt)}, expected "
                          f"{show_json(BUNDLE_FORMAT)})")
    version = doc.get("version")
    if not is_json_type(version, "integer") or version < 1:
        raise BundleError(what, f"version: unknown bundle version {show_json(version)} (this build reads version "
                          f"{BUNDLE_VERSION})")
    if version > BUNDLE_VERSION:
        raise BundleError(what, f"version: bundle version {version} is newer than this build reads "
                          f"({BUNDLE_VERSION}); update photon-fields or re-export with this version")
    if version not in READABLE_VERSIONS:
        raise BundleError(what, f"version: bundle version {version} is not supported (this build reads versions "
                          f"{', '.join(map(str, READABLE_VERSIONS))}); re-export the bundle")
    schema = manifest_schema(version)
    try:
        schema_check(doc, schema, "", schema)
    except BundleError as err:
        raise BundleError(f"{what}: {err.what}", err.problem) from None
    try:
        cfg = FieldConfig.from_dict(doc["field"])
    except (ValueError, TypeError, OverflowError) as exc:  # e.g. a base resolution beyond any float
        raise BundleError(f"{what}: field", str(exc)) from None
    for name, hg in (("position", cfg.position), ("direction", cfg.direction)):
        want = encoding_geometry(hg)
        for key, value in want.items():
            if doc["encodings"][name][key] != value:
                raise BundleError(f"{what}: encodings.{name}.{key}", f"does not match field.{name} "
                                  f"(expected {show_json(value)}): the "
                                  "bundle was made with another hash-grid definition")
    if doc["inputs"]["width"] != cfg.input_dims:
        raise BundleError(f"{what}: inputs.width", f"must be {cfg.input_dims} (the encodings' features + g), "
                          f"got {doc['inputs']['width']}")
    if doc["output"]["channels"] != cfg.output_dims:
        raise BundleError(f"{what}: output.channels", f"must be {cfg.output_dims} (RGB for each of "
                          f"field.light_channels = {cfg.light_channels}), got {doc['output']['channels']}")
    if doc["inputs"]["layout"] != input_layout(cfg):
        raise BundleError(f"{what}: inputs.layout", f"must be {json.dumps(input_layout(cfg))}")
    arrays = doc["tables"]["arrays"]
    if (SURFACE_ARRAY in arrays) != (cfg.surface is not None):
        raise BundleError(f"{what}: tables.arrays.{SURFACE_ARRAY}", "must be listed exactly when field.surface is set")
    for name, shape in table_shapes(cfg).items():
        got = tuple(arrays[name]["shape"])
        if got != shape:
            raise BundleError(f"{what}: tables.arrays.{name}.shape", f"must be {list(shape)} for field.{name}, "
                              f"got {list(got)}")
    return Manifest(cfg, np.array(doc["domain"]["bmin"], np.float64), np.array(doc["domain"]["bsize"], np.float64),
                    doc["scene_fingerprint"], doc["tables"]["dtype"], {k: dict(v) for k, v in doc["files"].items()},
                    dict(doc["training"]), doc, dict(doc["scene"]) if "scene" in doc else None)


def parse_manifest_bytes(data: bytes, what: str = MANIFEST_FILE) -> Manifest:
    """Decode, parse and validate manifest.json bytes (one-line :class:`BundleError` on any problem)."""
    if len(data) > MAX_MANIFEST_BYTES:
        raise BundleError(what, f"is {len(data)} bytes; a manifest is at most {MAX_MANIFEST_BYTES}")
    try:
        doc = json.loads(data.decode("utf-8"), parse_constant=_reject_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError) as exc:
        raise BundleError(what, f"not valid JSON ({exc})") from None
    return validate_manifest(doc, what)


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def check_table(manifest: Manifest, name: str, shape: tuple[int, ...], dtype: Any, what: str = TABLES_FILE) -> None:
    """One ``tables.npz`` array's shape and dtype against the manifest (both sides call this)."""
    want = table_shapes(manifest.config)[name]
    if tuple(shape) != want:
        raise BundleError(what, f"'{name}' has shape {tuple(shape)}, the manifest's field needs {want}")
    if np.dtype(dtype) != table_dtype(manifest, name):
        raise BundleError(what, f"'{name}' has dtype {np.dtype(dtype)}, the field needs {table_dtype(manifest, name)}")


def file_digest(path: str | Path, chunk: int = 1 << 22) -> tuple[str, int]:
    """sha256 (hex) and size in bytes of a file, read in chunks."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
            size += len(block)
    return h.hexdigest(), size
