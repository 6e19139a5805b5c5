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
                    ``FieldConfig.input_dims``); output ``encoded_radiance`` float32 (batch, 3 C) = L' of
                    Eq. 6 (C = ``field.light_channels``, 1 unless the field keeps lights apart); the
                    batch axis is dynamic (named ``batch``). One self-contained file (no external
                    data), opset :data:`ONNX_OPSET`.
``tables.npz``      two arrays, ``position`` (rows_p, F_p) and ``direction`` (rows_d, F_d), the flat hash
                    tables of :mod:`models_spec.hashgrid` (level l in rows ``table_offsets(cfg)[l] : ...``),
                    float32 or float16 as the manifest says; for a field with the surface input a third,
                    ``surface`` int8 (sx, sy, sz, 3), its grid (:mod:`models_spec.surface`); no pickles
                    (readers use ``np.load(allow_pickle=False)``)
==================  ================================================================================

Evaluating a bundle (what ``runtime.field.field.PhotonField.query`` does, and what any other runtime must do):
world position x -> ``normalize_position(x, bmin, bsize)`` (the manifest's ``domain``), unit camera-ray
travel direction d -> ``direction_input(d)`` (:mod:`photon_fields.models_spec.encoding`), both hash-encoded exactly as
:mod:`photon_fields.models_spec.hashgrid` defines (tiny-cuda-nn's HashGrid; the primes are repeated in the manifest),
concatenated with ``phase_features(g, phases, phase_encoding)`` (g, plus one tent or cubic B-spline weight per
phase when the field's ``phase_encoding`` is "tent" or "spline") in the column order of ``inputs.layout``, the
direction's columns times g when the field's ``direction_gain`` is "g" (``direction_gains``), the
ONNX MLP gives L', and Eq. 7 (``decode_radiance``, psi from the manifest) gives the radiance Q(x, d, g) that the
photon-map estimate (Eq. 5) supplies during training. With ``light_channels`` C > 1 the decoded output holds each
light's part (light l in columns 3 l .. 3 l + 2, the lights of ``scene.spec`` in order), and Q is their sum, each
part times its light's RGB flux factor relative to the trained one (1 for the scene trained for).

Manifest (version :data:`BUNDLE_VERSION`; :data:`MANIFEST_SCHEMA` is its JSON Schema, shipped as
``models_spec/manifest.schema.json``, generated from the dict, test-checked to be in sync)
----------------------------------------------------------------------------------------------------
- ``format`` = :data:`BUNDLE_FORMAT`, ``version`` = :data:`BUNDLE_VERSION` (an integer; a reader refuses
  a newer version instead of guessing);
- ``field``: :meth:`photon_fields.models_spec.encoding.FieldConfig.to_dict` (both encodings: levels, features,
  log2 table size, base resolution, per-level scale; MLP hidden width and layers; psi; the phase set G; the
  phase encoding, a key present only when it is not "scalar", so bundles written before it read unchanged;
  ``light_channels``, likewise present only when > 1, added without a version change; ``direction_gain``, present
  only when "g": the direction's columns of the features are multiplied by g before the MLP, added without a version
  change, since a reader that does not know the key refuses the bundle rather than render it wrong; ``surface``, the
  surface input's grid cells, present only for a field with that input, likewise);
- ``hash_primes``: tcnn's primes (:data:`photon_fields.models_spec.hashgrid.HASH_PRIMES`), listed so that a foreign
  runtime needs nothing but the manifest; a reader refuses other values;
- ``encodings``: per encoding the derived geometry (table rows, per-level resolution, table size, whether
  hashed): redundant with ``field``, and checked against it, so a definition drift cannot go unnoticed;
- ``domain``: ``bmin``, ``bsize`` (world box, 3 numbers each, bsize > 0);
- ``inputs``: ``width`` and ``layout`` (``[{"name", "start", "stop"}]`` for position, direction, g (its phase
  features: 1 or 1 + |G| columns) and, with the surface input, surface, in column order), the ONNX tensor names
  and batch axis name;
- ``output``: 3 channels per light channel (3 C), ``encoding`` "eq6-log10" (decode: ``10^(-L' psi)``);
- ``tables``: file, ``dtype`` of the hash tables (float32 | float16), array shapes (``surface`` listed exactly when
  the field has the surface input; int8 whatever ``dtype`` says);
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

The code, by concern (this module documents the format and re-exports every name, so callers import from here):
:mod:`~photon_fields.models_spec.bundle_layout` (file, array and tensor names, versions, :class:`BundleError`),
:mod:`~photon_fields.models_spec.bundle_schema` (:data:`MANIFEST_SCHEMA`, :func:`manifest_schema`),
:mod:`~photon_fields.models_spec.schema_check` (the JSON Schema subset interpreter) and
:mod:`~photon_fields.models_spec.bundle_manifest` (building and validating manifests, checking the tables and
file digests against one).

numpy and the standard library only (the runtime imports this with torch absent).
"""

from __future__ import annotations

from photon_fields.models_spec.bundle_layout import (
    BATCH_AXIS,
    BUNDLE_FILES,
    BUNDLE_FORMAT,
    BUNDLE_SUFFIX,
    BUNDLE_VERSION,
    MANIFEST_FILE,
    MAX_MANIFEST_BYTES,
    ONNX_FILE,
    ONNX_INPUT,
    ONNX_IR_VERSION,
    ONNX_OPSET,
    ONNX_OUTPUT,
    OUTPUT_ENCODING,
    READABLE_VERSIONS,
    SURFACE_ARRAY,
    SURFACE_DTYPE,
    TABLE_ARRAYS,
    TABLE_DTYPES,
    TABLES_FILE,
    BundleError,
)
from photon_fields.models_spec.bundle_manifest import (
    Manifest,
    build_manifest,
    check_table,
    encoding_geometry,
    file_digest,
    input_layout,
    manifest_text,
    parse_manifest_bytes,
    scene_record,
    table_dtype,
    table_shapes,
    training_summary,
    validate_manifest,
    validate_scene_record,
)
from photon_fields.models_spec.bundle_schema import MANIFEST_SCHEMA, SCHEMA_PATH, manifest_schema, schema_json
from photon_fields.models_spec.schema_check import schema_check as _schema_check  # noqa: F401  (tests use it)

__all__ = [
    "BATCH_AXIS", "BUNDLE_FILES", "BUNDLE_FORMAT", "BUNDLE_SUFFIX", "BUNDLE_VERSION", "MANIFEST_FILE",
    "MAX_MANIFEST_BYTES", "ONNX_FILE", "ONNX_INPUT", "ONNX_IR_VERSION", "ONNX_OPSET", "ONNX_OUTPUT", "OUTPUT_ENCODING",
    "READABLE_VERSIONS", "SURFACE_ARRAY", "SURFACE_DTYPE", "TABLE_ARRAYS", "TABLE_DTYPES", "TABLES_FILE", "BundleError",
    "MANIFEST_SCHEMA", "SCHEMA_PATH", "manifest_schema", "schema_json",
    "Manifest", "build_manifest", "check_table", "encoding_geometry", "file_digest", "input_layout", "manifest_text",
    "parse_manifest_bytes", "scene_record", "table_dtype", "table_shapes", "training_summary", "validate_manifest",
    "validate_scene_record",
]
