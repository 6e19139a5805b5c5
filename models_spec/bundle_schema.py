"""The bundle manifest's JSON Schema: :data:`MANIFEST_SCHEMA` is the one definition of the manifest's shape
(``models_spec/manifest.schema.json`` is generated from it, test-checked to be in sync), :func:`manifest_schema` the
schema of each readable version. The fields are documented in :mod:`photon_fields.models_spec.bundle`; the
interpreter that checks a manifest against the schema is :mod:`photon_fields.models_spec.schema_check`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from photon_fields.models_spec.bundle_layout import (
    BATCH_AXIS,
    BUNDLE_FORMAT,
    BUNDLE_VERSION,
    ONNX_FILE,
    ONNX_INPUT,
    ONNX_OUTPUT,
    OUTPUT_ENCODING,
    TABLE_DTYPES,
    TABLES_FILE,
)
from photon_fields.models_spec.encoding import MAX_LIGHT_CHANNELS, OUTPUT_CHANNELS
from photon_fields.models_spec.fingerprint import FINGERPRINT_PARTS
from photon_fields.models_spec.hashgrid import HASH_PRIMES
from photon_fields.models_spec.surface import SURFACE_MAX_CELLS

_SHA256 = "^[0-9a-f]{64}$"


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
            "name": {"type": "string", "enum": ["position", "direction", "g", "surface"]},
            "start": {"type": "integer", "minimum": 0},
            "stop": {"type": "integer", "minimum": 1},
        }),
        "table": _obj({"shape": {"type": "array", "items": {"type": "integer", "minimum": 1}, "minItems": 2,
                                 "maxItems": 2}}),
        "surface_table": _obj({"shape": {"type": "array", "items": {"type": "integer", "minimum": 1}, "minItems": 4,
                                         "maxItems": 4}}),
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
            "light_channels": {"type": "integer", "minimum": 2, "maximum": MAX_LIGHT_CHANNELS},
            "direction_gain": {"type": "string", "enum": ["g"]},
            "surface": {"type": "array", "items": {"type": "integer", "minimum": 1, "maximum": SURFACE_MAX_CELLS},
                        "minItems": 3, "maxItems": 3},
        }, required=["version", "position", "direction", "hidden_width", "hidden_layers", "psi", "phases"]),
        "hash_primes": {"type": "array", "const": [int(p) for p in HASH_PRIMES]},
        "encodings": _obj({"position": {"$ref": "#/$defs/geometry"}, "direction": {"$ref": "#/$defs/geometry"}}),
        "domain": _obj({"bmin": _num_array(3), "bsize": _num_array(3, exclusiveMinimum=0)}),
        "inputs": _obj({
            "width": {"type": "integer", "minimum": 2},
            "layout": {"type": "array", "items": {"$ref": "#/$defs/column_range"}, "minItems": 3, "maxItems": 4},
            "onnx_input": {"type": "string", "const": ONNX_INPUT},
            "onnx_output": {"type": "string", "const": ONNX_OUTPUT},
            "batch_axis": {"type": "string", "const": BATCH_AXIS},
        }),
        "output": _obj({"channels": {"type": "integer", "minimum": OUTPUT_CHANNELS,
                                     "maximum": OUTPUT_CHANNELS * MAX_LIGHT_CHANNELS},
                        "encoding": {"type": "string", "const": OUTPUT_ENCODING}}),
        "tables": _obj({
            "file": {"type": "string", "const": TABLES_FILE},
            "dtype": {"type": "string", "enum": list(TABLE_DTYPES)},
            "arrays": _obj({"position": {"$ref": "#/$defs/table"}, "direction": {"$ref": "#/$defs/table"},
                            "surface": {"$ref": "#/$defs/surface_table"}}, required=["position", "direction"]),
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
