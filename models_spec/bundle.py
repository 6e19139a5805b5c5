"""The field bundle: what a trained photon field hands from training (torch) to the runtime (no torch).

A bundle is a directory named ``NAME.pfn/`` (a directory, not an archive: the tables can be hundreds of MB
and are read straight from disk, and each file stays inspectable with ordinary tools) holding three files:

==================  ================================================================================
file                contents
==================  ================================================================================
``manifest.json``   format, version, the field's architecture, domain box, input layout, scene
                    fingerprint, training summary and the sha256 and size of the two other files
``field.onnx``      the MLP alone (paper Sec. 3.4, Fig. 5): input ``features`` float32 (batch, W) = the
                    concatenated hash-grid features of position and direction and g (W =
                    ``FieldConfig.input_dims``); output ``encoded_radiance`` float32 (batch, 3) = L' of
                    Eq. 6; the batch axis is dynamic (named ``batch``). One self-contained file (no
                    external data), opset :data:`ONNX_OPSET`.
``tables.npz``      two arrays, ``position`` (rows_p, F_p) and ``direction`` (rows_d, F_d), the flat hash
                    tables of :mod:`models_spec.hashgrid` (level l in rows ``table_offsets(cfg)[l] : ...``),
                    float32 or float16 as the manifest says; no pickles (readers use
                    ``np.load(allow_pickle=False)``)
==================  ================================================================================

Evaluating a bundle (what ``runtime.field.field.PhotonField.query`` does, and what any other runtime must do):
world position x -> ``normalize_position(x, bmin, bsize)`` (the manifest's ``domain``), unit camera-ray
travel direction d -> ``direction_input(d)`` (:mod:`photon_fields.models_spec.encoding`), both hash-encoded exactly as
:mod:`photon_fields.models_spec.hashgrid` defines (tiny-cuda-nn's HashGrid; the primes are repeated in the manifest),
concatenated with ``phase_features(g, phases, phase_encoding)`` (g, plus one tent or cubic B-spline weight per
phase when the field's ``phase_encoding`` is "tent" or "spline") in the column order of ``inputs.layout``, the
ONNX MLP gives L', and Eq. 7 (``decode_radiance``, psi from the manifest) gives the radiance Q(x, d, g) that the
photon-map estimate (Eq. 5) supplies during training.

Manifest (version :data:`BUNDLE_VERSION`; :data:`MANIFEST_SCHEMA` is its JSON Schema, shipped as
``models_spec/manifest.schema.json``, generated from the dict, test-checked to be in sync)
----------------------------------------------------------------------------------------------------
- ``format`` = :data:`BUNDLE_FORMAT`, ``version`` = :data:`BUNDLE_VERSION` (an integer; a reader refuses
  a newer version instead of guessing);
- ``field``: :meth:`photon_fields.models_spec.encoding.FieldConfig.to_dict` (both encodings: levels, features,
  log2 table size, base resolution, per-level scale; MLP hidden width and layers; psi; the phase set G; the
  phase encoding, a key present only when it is not "scalar", so bundles written before it read unchanged);
- ``hash_primes``: tcnn's primes (:data:`photon_fields.models_spec.hashgrid.HASH_PRIMES`), listed so that a foreign
  runtime needs nothing but the manifest; a reader refuses other values;
- ``encodings``: per encoding the derived geometry (table rows, per-level resolution, table size, whether
  hashed): redundant with ``field``, and checked against it, so a definition drift cannot go unnoticed;
- ``domain``: ``bmin``, ``bsize`` (world box, 3 numbers each, bsize > 0);
- ``inputs``: ``width`` and ``layout`` (``[{"name", "start", "stop"}]`` for position, direction, g (its phase
  features: 1 or 1 + |G| columns), in column order), the ONNX tensor names and batch axis name;
- ``output``: 3 channels, ``encoding`` "eq6-log10" (decode: ``10^(-L' psi)``);
- ``tables``: file, ``dtype`` (float32 | float16), array shapes;
- ``scene_fingerprint``: :func:`photon_fields.models_spec.fingerprint.scene_fingerprint` of the scene trained for;
- ``scene`` (version 2): the scene trained for, each entry null when unknown: ``name``; ``parts``, its
  per-part fingerprints ``{"volume", "transfer_function", "lights"}`` (:func:`photon_fields.models_spec.fingerprint.
  fingerprint_parts`), so that a bundle used for another scene can name what differs; ``spec``, the scene
  file that rebuilds it (``photon_fields.runtime.scene.scene`` format: volume by builtin name or absolute path, transfer
  function, lights, camera, phase; checked by that reader when used), so that ``pfn-render --method
  field`` without ``--scene`` renders the scene the field was trained for;
- ``training``: preset, steps, batch, final loss, validation (val_loss, val_rel_l1) or null, wall time;
- ``files``: ``{"field.onnx": {"sha256", "bytes"}, "tables.npz": {...}}``.

No creation time is stored: the same checkpoint gives byte-identical bundle files.

Versions. Version 2 added ``scene`` (required, entries nullable). Readers of version 1 only refuse a version 2
bundle in one line ("newer than this build reads ...; update"); this build reads both
(:data:`READABLE_VERSIONS`): a version 1 manifest is checked against the schema without ``scene`` and
loads with ``Manifest.scene`` None (a mismatch then says the parts cannot be compared, and a render
without ``--scene`` uses the default scene and says so). The exporter always writes :data:`BUNDLE_VERSION`.

Validation (:func:`validate_manifest`, used by the exporter on what it wrote and by the runtime on what it
reads): the first problem found is raised as a :class:`BundleError` whose message is one line naming the
field, e.g. ``manifest.json: field.position.levels: must be an integer >= 1, got "x"``. The validator
interprets the JSON Schema subset the schema uses (no jsonschema dependency): type, const, enum,
properties, required, additionalProperties, items, minItems, maxItems, minimum, maximum,
exclusiveMinimum, pattern, ``$ref`` to ``#/$defs/...``. Integers must be written without a fraction.

numpy and the standard library only (the runtime imports this with torch absent).
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.encoding import OUTPUT_CHANNELS, FieldConfig
from photon_fields.models_spec.fingerprint import FINGERPRINT_PARTS
from photon_fields.models_spec.hashgrid import HASH_PRIMES, HashGridConfig, level_specs, total_table_rows

BUNDLE_FORMAT = "photon-fields/field-bundle"
BUNDLE_VERSION = 2
#: Manifest versions this build reads (older ones against :func:`manifest_schema` of their version).
READABLE_VERSIONS = (1, 2)
BUNDLE_SUFFIX = ".pfn"
MANIFEST_FILE = "manifest.json"
ONNX_FILE = "field.onnx"
TABLES_FILE = "tables.npz"
BUNDLE_FILES = (MANIFEST_FILE, ONNX_FILE, TABLES_FILE)
#: The arrays of ``tables.npz``, in input-column order.
TABLE_ARRAYS = ("position", "direction")
TABLE_DTYPES = ("float32", "float16")
ONNX_INPUT = "features"
ONNX_OUTPUT = "encoded_radiance"
BATCH_AXIS = "batch"
#: Opset 17 / IR 8: old enough for every onnxruntime this project accepts (>= 1.17), and the graph only
#: needs MatMul and Relu.
ONNX_OPSET = 17
ONNX_IR_VERSION = 8
OUTPUT_ENCODING = "eq6-log10"
#: A manifest is a few KB; anything far larger is not one (and is not read into memory).
MAX_MANIFEST_BYTES = 1 << 20

_SHA256 = "^[0-9a-f]{64}$"


class BundleError(ValueError):
    """A bundle (or a manifest) is not acceptable. ``str(err)`` is one line: ``'<what>: <problem>'``; the
    runtime re-raises it as ``photon_fields.runtime.errors.InputError`` with the same text."""

    def __init__(self, what: str, problem: str) -> None:
        self.what = str(what)
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{self.what}: {self.problem}")


# ----------------------------------------------------------------------------------------------------
# The schema (the one definition of the manifest's shape; manifest.schema.json is generated from it)
# ----------------------------------------------------------------------------------------------------


def _obj(props: dict[str, Any], required: Sequence[str] | None = None) -> dict[str, Any]:
    return {"type": "object", "properties": props, "required": list(props if required is None else required),
            "additionalProperties": False}


def _num_array(n: int, **item: Any) -> dict[str, Any]:
    return {"type": "array", "items": {"type": "number", **item}, "minItems": n, "maxItems": n}


_FILE_ENTRY = _obj({"sha256": {"type": "string", "pattern": _SHA256}, "bytes": {"type": "integer", "minimum": 1}})
_INT_LIST = {"type": "array", "items": {"type": "integer", "minimum": 0}, "minItems": 1}

MANIFEST_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "$id": f"https://photon-fields/schemas/field-bundle-manifest-v{BUNDLE_VERSION}.json",
    "title": "photon-fields field bundle manifest",
    "description": "manifest.json of a NAME.pfn bundle (models_spec/bundle.py documents every field)",
    "$defs": {
        "hashgrid": _obj({
            "dims": {"type": "integer", "enum": [2, 3]},
            "levels": {"type": "integer", "minimum": 1, "maximum": 32},
            "features": {"type": "integer", "enum": [1, 2, 4, 8]},
            "log2_table_size": {"type": "integer", "minimum": 1, "maximum": 31},
            "base_resolution": {"type": "integer", "minimum": 1},
            "per_level_scale": {"type": "number", "minimum": 1},
        }),
        "geometry": _obj({
            "table_rows": {"type": "integer", "minimum": 1},
            "level_resolutions": _INT_LIST,
            "level_table_sizes": _INT_LIST,
            "level_hashed": {"type": "array", "items": {"type": "boolean"}, "minItems": 1},
        }),
        "column_range": _obj({
            "name": {"type": "string", "enum": ["position", "direction", "g"]},
            "start": {"type": "integer", "minimum": 0},
            "stop": {"type": "integer", "minimum": 1},
        }),
        "table": _obj({"shape": {"type": "array", "items": {"type": "integer", "minimum": 1}, "minItems": 2,
                                 "maxItems": 2}}),
        "nullable_number": {"type": ["number", "null"]},
    },
    **_obj({
        "format": {"type": "string", "const": BUNDLE_FORMAT},
        "version": {"type": "integer", "const": BUNDLE_VERSION},
        "field": _obj({
            "version": {"type": "integer", "const": 1},
            "position": {"$ref": "#/$defs/hashgrid"},
            "direction": {"$ref": "#/$defs/hashgrid"},
            "hidden_width": {"type": "integer", "minimum": 1, "maximum": 4096},
            "hidden_layers": {"type": "integer", "minimum": 1, "maximum": 64},
            "psi": {"type": "number", "exclusiveMinimum": 0, "maximum": 30},
            "phases": {"type": "array", "items": {"type": "number", "minimum": -1, "maximum": 1}, "minItems": 1},
            "phase_encoding": {"type": "string", "enum": ["tent", "spline"]},
        }, required=["version", "position", "direction", "hidden_width", "hidden_layers", "psi", "phases"]),
        "hash_primes": {"type": "array", "const": [int(p) for p in HASH_PRIMES]},
        "encodings": _obj({"position": {"$ref": "#/$defs/geometry"}, "direction": {"$ref": "#/$defs/geometry"}}),
        "domain": _obj({"bmin": _num_array(3), "bsize": _num_array(3, exclusiveMinimum=0)}),
        "inputs": _obj({
            "width": {"type": "integer", "minimum": 2},
            "layout": {"type": "array", "items": {"$ref": "#/$defs/column_range"}, "minItems": 3, "maxItems": 3},
            "onnx_input": {"type": "string", "const": ONNX_INPUT},
            "onnx_output": {"type": "string", "const": ONNX_OUTPUT},
            "batch_axis": {"type": "string", "const": BATCH_AXIS},
        }),
        "output": _obj({"channels": {"type": "integer", "const": OUTPUT_CHANNELS},
                        "encoding": {"type": "string", "const": OUTPUT_ENCODING}}),
        "tables": _obj({
            "file": {"type": "string", "const": TABLES_FILE},
            "dtype": {"type": "string", "enum": list(TABLE_DTYPES)},
            "arrays": _obj({"position": {"$ref": "#/$defs/table"}, "direction": {"$ref": "#/$defs/table"}}),
        }),
        "onnx": _obj({"file": {"type": "string", "const": ONNX_FILE},
                      "opset": {"type": "integer", "minimum": 1}}),
        "scene_fingerprint": {"type": "string", "pattern": _SHA256},
        "scene": _obj({
            "name": {"type": ["string", "null"]},
            "parts": {**_obj({p: {"type": "string", "pattern": _SHA256} for p in FINGERPRINT_PARTS}),
                      "type": ["object", "null"]},
            "spec": {"type": ["object", "null"]},
        }),
        "training": _obj({
            "preset": {"type": ["string", "null"]},
            "steps": {"type": "integer", "minimum": 0},
            "batch": {"type": ["integer", "null"], "minimum": 1},
            "final_loss": {"$ref": "#/$defs/nullable_number"},
            "validation": {"type": ["object", "null"], "additionalProperties": {"type": ["number", "null"]}},
            "wall_s": {"$ref": "#/$defs/nullable_number"},
        }),
        "files": _obj({ONNX_FILE: _FILE_ENTRY, TABLES_FILE: _FILE_ENTRY}),
    }),
}


def manifest_schema(version: int = BUNDLE_VERSION) -> dict[str, Any]:
    """The schema a manifest of ``version`` (one of :data:`READABLE_VERSIONS`) is checked against."""
    if version == BUNDLE_VERSION:
        return MANIFEST_SCHEMA
    if version == 1:  # before ``scene``
        schema = json.loads(json.dumps(MANIFEST_SCHEMA))
        del schema["properties"]["scene"]
        schema["required"].remove("scene")
        schema["properties"]["version"]["const"] = 1
        schema["$id"] = "https://photon-fields/schemas/field-bundle-manifest-v1.json"
        return schema
    raise ValueError(f"no schema for bundle version {version!r}")


def schema_json() -> str:
    """The schema as the text of ``models_spec/manifest.schema.json``."""
    return json.dumps(MANIFEST_SCHEMA, indent=2) + "\n"


SCHEMA_PATH = Path(__file__).with_name("manifest.schema.json")


# ----------------------------------------------------------------------------------------------------
# A small JSON Schema interpreter (the subset MANIFEST_SCHEMA uses)
# ----------------------------------------------------------------------------------------------------

_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}


def _is_type(value: Any, name: str) -> bool:
    if name == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if name == "number":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        try:  # JSON integers are unbounded; a "number" must also be a finite float64
            return math.isfinite(float(value))
        except OverflowError:
            return False
    return isinstance(value, _TYPES[name])


def _show(value: Any) -> str:
    try:
        text = json.dumps(value)
    except (TypeError, ValueError):
        text = type(value).__name__
    return text if len(text) <= 60 else text[:57] + "..."


def _type_phrase(types: Sequence[str]) -> str:
    words = {"integer": "an integer", "number": "a finite number", "object": "an object", "array": "an array",
             "string": "a string", "boolean": "true or false", "null": "null"}
    return " or ".join(words[t] for t in types)


def _json_equal(a: Any, b: Any) -> bool:
    """JSON Schema equality for const / enum: like ==, except that true / false never equal the numbers 1 / 0
    (Python's True == 1 let ``true`` pass a ``const`` of 1; found by comparing with jsonschema)."""
    if isinstance(a, bool) or isinstance(b, bool):
        return type(a) is type(b) and a == b
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_json_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_json_equal(a[k], b[k]) for k in a)
    return a == b


def _schema_check(value: Any, schema: Mapping[str, Any], path: str, root: Mapping[str, Any]) -> None:
    """Raise BundleError(path, problem) for the first violation, in schema order."""
    if "$ref" in schema:
        ref = schema["$ref"]
        assert ref.startswith("#/$defs/"), ref  # the only kind of reference the schema uses
        schema = root["$defs"][ref[len("#/$defs/"):]]
    where = path or "manifest"
    if "type" in schema:
        types = [schema["type"]] if isinstance(schema["type"], str) else list(schema["type"])
        if not any(_is_type(value, t) for t in types):
            raise BundleError(where, f"must be {_type_phrase(types)}, got {_show(value)}")
    if "const" in schema and not _json_equal(value, schema["const"]):
        raise BundleError(where, f"must be {_show(schema['const'])}, got {_show(value)}")
    if "enum" in schema and not any(_json_equal(value, v) for v in schema["enum"]):
        raise BundleError(where, f"must be one of {', '.join(_show(v) for v in schema['enum'])}, got {_show(value)}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            raise BundleError(where, f"must be >= {schema['minimum']}, got {_show(value)}")
        if "maximum" in schema and value > schema["maximum"]:
            raise BundleError(where, f"must be <= {schema['maximum']}, got {_show(value)}")
        if "exclusiveMinimum" in schema and not value > schema["exclusiveMinimum"]:
            raise BundleError(where, f"must be > {schema['exclusiveMinimum']}, got {_show(value)}")
    if isinstance(value, str) and "pattern" in schema and not re.search(schema["pattern"], value):
        raise BundleError(where, f"must match {schema['pattern']}, got {_show(value)}")
    if isinstance(value, list):
        if "minItems" in schema and len(value) < schema["minItems"]:
            raise BundleError(where, f"must have at least {schema['minItems']} entries, got {len(value)}")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            raise BundleError(where, f"must have at most {schema['maxItems']} entries, got {len(value)}")
        if "items" in schema:
            for i, item in enumerate(value):
                _schema_check(item, schema["items"], f"{path}[{i}]", root)
    if isinstance(value, dict):
        prefix = f"{path}." if path else ""
        for key in schema.get("required", []):
            if key not in value:
                raise BundleError(f"{prefix}{key}", "missing")
        props = schema.get("properties", {})
        for key, sub in props.items():
            if key in value:
                _schema_check(value[key], sub, f"{prefix}{key}", root)
        extra = schema.get("additionalProperties", True)
        for key in value:
            if key in props:
                continue
            if extra is False:
                raise BundleError(f"{prefix}{key}", "unknown field")
            if isinstance(extra, dict):
                _schema_check(value[key], extra, f"{prefix}{key}", root)


# ----------------------------------------------------------------------------------------------------
# Building and validating manifests
# ----------------------------------------------------------------------------------------------------


def encoding_geometry(cfg: HashGridConfig) -> dict[str, Any]:
    """Derived per-level geometry of one hash grid, as the manifest lists it."""
    specs = level_specs(cfg)
    return {"table_rows": total_table_rows(cfg), "level_resolutions": [s.resolution for s in specs],
            "level_table_sizes": [s.table_size for s in specs], "level_hashed": [bool(s.hashed) for s in specs]}


def input_layout(cfg: FieldConfig) -> list[dict[str, Any]]:
    """Column ranges of the MLP input: position features, direction features, g (Sec. 3.4, Fig. 5)."""
    p, d = cfg.position.output_dims, cfg.direction.output_dims
    return [{"name": "position", "start": 0, "stop": p}, {"name": "direction", "start": p, "stop": p + d},
            {"name": "g", "start": p + d, "stop": p + d + cfg.phase_dims}]


def table_shapes(cfg: FieldConfig) -> dict[str, tuple[int, int]]:
    """Expected shape of each ``tables.npz`` array."""
    return {"position": (total_table_rows(cfg.position), cfg.position.features),
            "direction": (total_table_rows(cfg.direction), cfg.direction.features)}


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
    _schema_check(record, sub, "scene", MANIFEST_SCHEMA)


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
        "output": {"channels": OUTPUT_CHANNELS, "encoding": OUTPUT_ENCODING},
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
        raise BundleError(what, f"not a photon-field bundle manifest (format {_show(fmt)}, expected "
                          f"{_show(BUNDLE_FORMAT)})")
    version = doc.get("version")
    if not _is_type(version, "integer") or version < 1:
        raise BundleError(what, f"version: unknown bundle version {_show(version)} (this build reads version "
                          f"{BUNDLE_VERSION})")
    if version > BUNDLE_VERSION:
        raise BundleError(what, f"version: bundle version {version} is newer than this build reads "
                          f"({BUNDLE_VERSION}); update photon-fields or re-export with this version")
    if version not in READABLE_VERSIONS:
        raise BundleError(what, f"version: bundle version {version} is not supported (this build reads versions "
                          f"{', '.join(map(str, READABLE_VERSIONS))}); re-export the bundle")
    schema = manifest_schema(version)
    try:
        _schema_check(doc, schema, "", schema)
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
                                  f"(expected {_show(value)}): the "
                                  "bundle was made with another hash-grid definition")
    if doc["inputs"]["width"] != cfg.input_dims:
        raise BundleError(f"{what}: inputs.width", f"must be {cfg.input_dims} (the encodings' features + g), "
                          f"got {doc['inputs']['width']}")
    if doc["inputs"]["layout"] != input_layout(cfg):
        raise BundleError(f"{what}: inputs.layout", f"must be {json.dumps(input_layout(cfg))}")
    for name, shape in table_shapes(cfg).items():
        got = tuple(doc["tables"]["arrays"][name]["shape"])
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
    if np.dtype(dtype) != np.dtype(manifest.tables_dtype):
        raise BundleError(what, f"'{name}' has dtype {np.dtype(dtype)}, the manifest says {manifest.tables_dtype}")


def file_digest(path: str | Path, chunk: int = 1 << 22) -> tuple[str, int]:
    """sha256 (hex) and size in bytes of a file, read in chunks."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
            size += len(block)
    return h.hexdigest(), size
