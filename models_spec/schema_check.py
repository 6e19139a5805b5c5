"""A small JSON Schema interpreter: the subset the bundle manifest's schema
(:data:`photon_fields.models_spec.bundle_schema.MANIFEST_SCHEMA`) uses, so that validating a manifest needs no
jsonschema dependency: type, const, enum, properties, required, additionalProperties, items, minItems, maxItems,
minimum, maximum, exclusiveMinimum, pattern, ``$ref`` to ``#/$defs/...``. Integers must be written without a
fraction, numbers must be finite. :func:`schema_check` raises the first violation, in schema order, as a one-line
:class:`photon_fields.models_spec.bundle_layout.BundleError` naming the field.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

from photon_fields.models_spec.bundle_layout import BundleError

_TYPES = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}


def is_json_type(value: Any, name: str) -> bool:
    """Whether ``value`` (parsed JSON) is of the JSON Schema type ``name`` (a bool is no integer or number)."""
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


def show_json(value: Any) -> str:
    """``value`` as JSON for a message, cut to 60 characters."""
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


def schema_check(value: Any, schema: Mapping[str, Any], path: str, root: Mapping[str, Any]) -> None:
    """Raise BundleError(path, problem) for the first violation, in schema order."""
    if "$ref" in schema:
        ref = schema["$ref"]
        assert ref.startswith("#/$defs/"), ref  # the only kind of reference the schema uses
        schema = root["$defs"][ref[len("#/$defs/"):]]
    where = path or "manifest"
    if "type" in schema:
        types = [schema["type"]] if isinstance(schema["type"], str) else list(schema["type"])
        if not any(is_json_type(value, t) for t in types):
            raise BundleError(where, f"must be {_type_phrase(types)}, got {show_json(value)}")
    if "const" in schema and not _json_equal(value, schema["const"]):
        raise BundleError(where, f"must be {show_json(schema['const'])}, got {show_json(value)}")
    if "enum" in schema and not any(_json_equal(value, v) for v in schema["enum"]):
        raise BundleError(where, f"must be one of {', '.join(show_json(v) for v in schema['enum'])}, got "
                          f"{show_json(value)}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            raise BundleError(where, f"must be >= {schema['minimum']}, got {show_json(value)}")
        if "maximum" in schema and value > schema["maximum"]:
            raise BundleError(where, f"must be <= {schema['maximum']}, got {show_json(value)}")
        if "exclusiveMinimum" in schema and not value > schema["exclusiveMinimum"]:
            raise BundleError(where, f"must be > {schema['exclusiveMinimum']}, got {show_json(value)}")
    if isinstance(value, str) and "pattern" in schema and not re.search(schema["pattern"], value):
        raise BundleError(where, f"must match {schema['pattern']}, got {show_json(value)}")
    if isinstance(value, list):
        if "minItems" in schema and len(value) < schema["minItems"]:
            raise BundleError(where, f"must have at least {schema['minItems']} entries, got {len(value)}")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            raise BundleError(where, f"must have at most {schema['maxItems']} entries, got {len(value)}")
        if "items" in schema:
            for i, item in enumerate(value):
                schema_check(item, schema["items"], f"{path}[{i}]", root)
    if isinstance(value, dict):
        prefix = f"{path}." if path else ""
        for key in schema.get("required", []):
            if key not in value:
                raise BundleError(f"{prefix}{key}", "missing")
        props = schema.get("properties", {})
        for key, sub in props.items():
            if key in value:
                schema_check(value[key], sub, f"{prefix}{key}", root)
        extra = schema.get("additionalProperties", True)
        for key in value:
            if key in props:
                continue
            if extra is False:
                raise BundleError(f"{prefix}{key}", "unknown field")
            if isinstance(extra, dict):
                schema_check(value[key], extra, f"{prefix}{key}", root)
