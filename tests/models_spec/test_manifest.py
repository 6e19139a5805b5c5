"""The bundle manifest contract (photon_fields.models_spec.bundle): schema file in sync, validator accepts what the
exporter builds and names the first bad field in one line, versions are refused with their own words."""

from __future__ import annotations

import copy
import json
import subprocess
import sys

import pytest

from photon_fields.models_spec.bundle import (
    BUNDLE_VERSION,
    MANIFEST_SCHEMA,
    SCHEMA_PATH,
    BundleError,
    build_manifest,
    input_layout,
    manifest_text,
    parse_manifest_bytes,
    schema_json,
    training_summary,
    validate_manifest,
)
from photon_fields.models_spec.encoding import FieldConfig
from photon_fields.models_spec.hashgrid import HASH_PRIMES, HashGridConfig, total_table_rows

CFG = FieldConfig(HashGridConfig(3, 5, 2, 10, 4, 1.6), HashGridConfig(2, 3, 4, 8, 4, 2.0), 32, 2, 5.0,
                  (-0.75, 0.0, 0.75))


def good_manifest() -> dict:
    files = {"field.onnx": {"sha256": "1" * 64, "bytes": 100}, "tables.npz": {"sha256": "2" * 64, "bytes": 200}}
    training = training_summary(preset="tiny", steps=50, batch=1024, final_loss=float("nan"),
                                validation={"step": 50, "val_loss": 0.1, "val_rel_l1": 0.3}, wall_s=2.5)
    return build_manifest(CFG, bmin=[-0.5, -0.4, -0.3], bsize=[1.0, 0.8, 0.6], scene_fingerprint="a" * 64,
                          training=training, tables_dtype="float32", files=files)


def test_schema_file_is_generated_from_the_dict() -> None:
    assert SCHEMA_PATH.read_text() == schema_json(), (
        "regenerate: python -c 'from photon_fields.models_spec.bundle import *; SCHEMA_PATH.write_text(schema_json())'")
    assert json.loads(SCHEMA_PATH.read_text()) == MANIFEST_SCHEMA
    assert MANIFEST_SCHEMA["properties"]["hash_primes"]["const"] == [int(p) for p in HASH_PRIMES]


def _leaf_paths(doc: object, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _leaf_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out += _leaf_paths(v, (*prefix, i))
    return out


def test_schema_agrees_with_jsonschema() -> None:
    """The in-house validator interprets a subset of JSON Schema (models_spec.bundle): it must accept and refuse
    exactly what the reference implementation does, on the good manifest and on every single-field damage of
    it (each field deleted or replaced by a value of another type or out of range). jsonschema is a test
    dependency (pyproject's test extra), so this runs everywhere."""
    import jsonschema

    from photon_fields.models_spec.bundle import _schema_check

    jsonschema.Draft202012Validator.check_schema(MANIFEST_SCHEMA)
    reference = jsonschema.Draft202012Validator(MANIFEST_SCHEMA)
    good = good_manifest()
    reference.validate(good)
    checked = 0
    for path in _leaf_paths(good):
        for value in (None, "x", -1, 0.5, 10**12, True, [], {}, "delete"):
            doc = copy.deepcopy(good)
            node = doc
            for k in path[:-1]:
                node = node[k]
            if value == "delete":
                if not isinstance(node, dict):
                    continue
                del node[path[-1]]
            else:
                node[path[-1]] = value
            try:
                _schema_check(doc, MANIFEST_SCHEMA, "", MANIFEST_SCHEMA)
                ours = True
            except BundleError:
                ours = False
            assert ours == reference.is_valid(doc), (path, value, ours)
            checked += 1
    assert checked > 500


def test_good_manifest_round_trips() -> None:
    doc = good_manifest()
    text = manifest_text(doc)
    assert text == manifest_text(good_manifest())  # deterministic text
    m = parse_manifest_bytes(text.encode())
    assert m.config == CFG and m.input_width == 5 * 2 + 3 * 4 + 1
    assert list(m.bmin) == [-0.5, -0.4, -0.3] and m.tables_dtype == "float32"
    assert m.training["final_loss"] is None  # NaN is not JSON: written as null
    assert m.training["validation"] == {"val_loss": 0.1, "val_rel_l1": 0.3}
    assert doc["inputs"]["layout"] == input_layout(CFG)
    assert doc["tables"]["arrays"]["position"]["shape"] == [total_table_rows(CFG.position), 2]


def _set(doc: dict, path: str, value: object) -> None:
    keys = path.split(".")
    for k in keys[:-1]:
        doc = doc[int(k)] if isinstance(doc, list) else doc[k]
    if value is _DELETE:
        del doc[keys[-1]]
    else:
        doc[keys[-1]] = value


_DELETE = object()

BAD = [
    ("format", "other", "not a photon-field bundle manifest"),
    ("version", BUNDLE_VERSION + 1, "newer than this build reads"),
    ("version", 0, "unknown bundle version 0"),
    ("version", "1", "unknown bundle version \"1\""),
    ("field.position.levels", "x", "field.position.levels: must be an integer"),
    ("field.position.levels", 0, "field.position.levels: must be >= 1"),
    ("field.direction.features", 3, "field.direction.features: must be one of"),
    ("field.psi", 0, "field.psi: must be > 0"),
    ("field.phases", [], "field.phases: must have at least 1"),
    ("field.hidden_width", 1.5, "field.hidden_width: must be an integer"),
    ("hash_primes", [1, 2, 3], "hash_primes: must be [1, 2654435761, 805459861]"),
    ("domain.bsize", [1.0, 0.0, 1.0], "domain.bsize[1]: must be > 0"),
    ("domain.bmin", [0, 0], "domain.bmin: must have at least 3"),
    ("domain.bmin", _DELETE, "domain.bmin: missing"),
    ("inputs.width", 99, "inputs.width: must be 23"),
    ("inputs.layout.1.start", 7, "inputs.layout: must be"),
    ("tables.dtype", "float64", "tables.dtype: must be one of"),
    ("tables.arrays.position.shape", [10, 2], "tables.arrays.position.shape: must be ["),
    ("encodings.position.level_hashed", [False] * 5, "another hash-grid definition"),
    ("scene_fingerprint", "xyz", "scene_fingerprint: must match"),
    ("training.steps", -1, "training.steps: must be >= 0"),
    ("extra", 1, "extra: unknown field"),
    # JSON integers are unbounded: beyond float64 they are not numbers, and no config survives them.
    ("domain.bmin", [10**400, 0, 0], "domain.bmin[0]: must be a finite number"),
    ("training.wall_s", -(10**400), "training.wall_s: must be a finite number or null"),
    ("field.position.base_resolution", 10**400, "field: "),
]


@pytest.mark.parametrize("path, value, expect", BAD, ids=lambda v: "<deleted>" if v is _DELETE else str(v)[:30])
def test_validator_names_the_first_problem_in_one_line(path: str, value: object, expect: str) -> None:
    doc = copy.deepcopy(good_manifest())
    if path == "extra":
        doc["extra"] = value
    else:
        _set(doc, path, value)
    with pytest.raises(BundleError) as err:
        validate_manifest(doc)
    msg = str(err.value)
    assert "\n" not in msg and msg.startswith("manifest.json")
    assert expect in msg, msg


def test_missing_file_entry_and_non_json() -> None:
    doc = good_manifest()
    del doc["files"]["field.onnx"]
    with pytest.raises(BundleError, match=r"files\.field\.onnx: missing"):
        validate_manifest(doc)
    for data, match in ((b"{", "not valid JSON"), (b"\xff\xfe", "not valid JSON"), (b"[1]", "must be a JSON object"),
                        (manifest_text(good_manifest()).replace("0.1", "NaN").encode(), "not valid JSON")):
        with pytest.raises(BundleError, match=match):
            parse_manifest_bytes(data)


def test_models_spec_bundle_needs_no_torch_or_onnx() -> None:
    code = ("import sys, photon_fields.models_spec.bundle; "
            "bad = {'torch', 'onnx', 'onnxruntime', 'numba'} & set(sys.modules); assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


# ----------------------------------------------------------------------------------------------------------
# Version 2: the ``scene`` entry (issue 11); version 1 manifests are still read


PARTS = {"volume": "1" * 64, "transfer_function": "2" * 64, "lights": "3" * 64}


def v1_manifest() -> dict:
    doc = good_manifest()
    del doc["scene"]
    doc["version"] = 1
    return doc


def test_scene_entry_round_trips_and_defaults_to_unknown() -> None:
    from photon_fields.models_spec.bundle import scene_record

    assert BUNDLE_VERSION == 2 and good_manifest()["scene"] == {"name": None, "parts": None, "spec": None}
    spec = {"name": "s", "volume": {"builtin": "blobs", "resolution": 16}}
    doc = good_manifest()
    doc["scene"] = scene_record("s", PARTS, spec)
    m = parse_manifest_bytes(manifest_text(doc).encode())
    assert m.scene == {"name": "s", "parts": PARTS, "spec": spec} and m.scene_parts == PARTS


def test_version_1_manifests_are_still_read() -> None:
    m = validate_manifest(v1_manifest())
    assert m.scene is None and m.scene_parts is None and m.config == CFG
    doc = v1_manifest()
    doc["scene"] = {"name": None, "parts": None, "spec": None}  # version 1 had no scene: refused, by name
    with pytest.raises(BundleError, match="manifest.json: scene: unknown field"):
        validate_manifest(doc)
    with pytest.raises(BundleError, match="version: unknown bundle version 0"):
        validate_manifest({**v1_manifest(), "version": 0})


@pytest.mark.parametrize(("path", "value", "expect"), [
    ("scene", _DELETE, "scene: missing"),
    ("scene.parts", {**PARTS, "light": "4" * 64}, "scene.parts.light: unknown field"),
    ("scene.parts", {"volume": "1" * 64}, "scene.parts.transfer_function: missing"),
    ("scene.parts", {**PARTS, "lights": "x"}, "scene.parts.lights: must match"),
    ("scene.spec", "vortex", "scene.spec: must be an object or null"),
    ("scene.name", 3, "scene.name: must be a string or null"),
    ("scene.extra", 1, "scene.extra: unknown field"),
])
def test_scene_entry_is_strict(path: str, value: object, expect: str) -> None:
    doc = copy.deepcopy(good_manifest())
    _set(doc, path, value)
    with pytest.raises(BundleError) as err:
        validate_manifest(doc)
    assert expect in str(err.value) and "\n" not in str(err.value), str(err.value)
