"""Reading a ``NAME.pfn`` bundle from disk (format: :mod:`photon_fields.models_spec.bundle`), validating every byte.

:func:`read_bundle` is what :meth:`photon_fields.runtime.field.field.PhotonField.load` builds a field from. Every
refusal is a one-line :class:`photon_fields.runtime.errors.InputError` naming the file and the problem: bundle or
file missing, manifest not JSON / failing the schema / another format / a newer version, a file whose size
or sha256 differs from the manifest (corrupt, truncated, replaced), a tables.npz with other arrays, another
shape or dtype, non-finite values or a pickled object array (refused, never unpickled), an ONNX model with
external data, failing ``onnx.checker``, or with an input width other than the encodings' features + 1,
and a scene fingerprint mismatch (unless forced: then a warning line names what differs). A scene whose lights differ
from the trained ones only by a common factor of their flux (a light's power or colour edited, same kinds and
geometry; :mod:`photon_fields.runtime.scene.light_rescale`) is no mismatch: L_i is that factor times the trained
one, exactly, and ``light_scale`` says by how much; for a field that keeps its lights apart (``light_channels``)
each light's factor may differ (``light_scale`` (L, 3)).

:func:`scene_for_bundle` rebuilds the scene a bundle records, for renders that name no scene.
"""

from __future__ import annotations

import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.bundle import (
    MANIFEST_FILE,
    MAX_MANIFEST_BYTES,
    ONNX_FILE,
    ONNX_INPUT,
    ONNX_OUTPUT,
    SURFACE_ARRAY,
    TABLES_FILE,
    BundleError,
    Manifest,
    check_table,
    file_digest,
    parse_manifest_bytes,
    table_shapes,
)
from photon_fields.models_spec.fingerprint import mismatch_detail
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.field.hashgrid import aligned_table
from photon_fields.runtime.scene.light_rescale import scene_rescale


@dataclass
class BundleContents:
    """A validated bundle: its manifest, the hash tables (float32, rows aligned for the encoder), the ONNX
    model's bytes and, when a bundle of another scene was forced, the one-line warning to show."""

    path: Path
    manifest: Manifest
    tables: dict[str, np.ndarray]
    onnx_path: Path
    onnx_bytes: bytes
    scene_warning: str | None = None
    light_scale: np.ndarray | None = None
    """The RGB factor (3,) L_i takes for the expected lights (None: the trained lights, or a forced mismatch)."""


def read_bundle(path: str | os.PathLike[str], *, expected_fingerprint: str | None = None,
                expected_parts: dict[str, str] | None = None, force: bool = False,
                expected_lights: list[dict[str, Any]] | None = None) -> BundleContents:
    """Read and validate the bundle at ``path`` (module docstring). ``expected_fingerprint`` (and
    ``expected_parts``, to name what differs) refuse a bundle trained for another scene unless ``force``;
    ``expected_lights`` (the scene's lights as :func:`photon_fields.runtime.scene.lights.light_identity` dicts, with
    ``expected_parts``) accept one whose only difference is a rescale of the lights' flux (``light_scale``)."""
    bundle = Path(path)
    manifest = read_manifest(bundle)
    warning = None
    other_scene = expected_fingerprint is not None and manifest.scene_fingerprint != expected_fingerprint
    scale = _light_rescale(manifest, expected_parts, expected_lights) if other_scene else None
    if other_scene and scale is None:
        other = f"another scene{_trained_name(manifest)}: {mismatch_detail(expected_parts, manifest.scene_parts)}"
        if not force:
            raise InputError(str(bundle), f"was trained for {other}; retrain, or force to use it anyway")
        warning = f"{bundle} was trained for {other}; L_i will be wrong"
    onnx_path = _check_file(bundle, ONNX_FILE, manifest.files[ONNX_FILE])
    tables_path = _check_file(bundle, TABLES_FILE, manifest.files[TABLES_FILE])
    data = onnx_path.read_bytes()
    _check_onnx(onnx_path, data, manifest)
    tables = _load_tables(tables_path, manifest)
    return BundleContents(bundle, manifest, tables, onnx_path, data, warning, scale)


def _light_rescale(manifest: Manifest, expected_parts: dict[str, str] | None,
                   expected_lights: list[dict[str, Any]] | None) -> np.ndarray | None:
    """The flux factor from the bundle's trained lights to ``expected_lights`` when the lights are all that
    differs (the volume's and transfer function's fingerprints match) and the bundle records its scene's lights:
    RGB (3,), or for a field with one output per light one factor per light (L, 3); else None."""
    if expected_lights is None or expected_parts is None:
        return None
    spec = (manifest.scene or {}).get("spec") or {}
    return scene_rescale(manifest.scene_parts, spec.get("lights"), expected_parts, expected_lights,
                         manifest.config.light_channels)


def _bundle_error(err: BundleError, bundle: Path) -> InputError:
    return InputError(f"{bundle}/{err.what}" if not err.what.startswith(str(bundle)) else err.what, err.problem)


def _read_manifest(bundle: Path) -> Manifest:
    path = bundle / MANIFEST_FILE
    if not path.is_file():
        raise InputError(str(path), "missing: not a photon-field bundle (no manifest.json)")
    size = path.stat().st_size
    if size > MAX_MANIFEST_BYTES:
        raise InputError(str(path), f"is {size} bytes; a manifest is at most {MAX_MANIFEST_BYTES}")
    try:
        return parse_manifest_bytes(path.read_bytes(), MANIFEST_FILE)
    except BundleError as err:
        raise _bundle_error(err, bundle) from None


def read_manifest(path: str | os.PathLike[str]) -> Manifest:
    """The validated manifest of the bundle at ``path`` (one-line InputError), without loading the rest."""
    bundle = Path(path)
    if not bundle.exists():
        raise InputError(str(bundle), "bundle not found")
    if not bundle.is_dir():
        raise InputError(str(bundle), "is a file; a bundle is a NAME.pfn directory (manifest.json, field.onnx, "
                         "tables.npz)")
    return _read_manifest(bundle)


def _trained_name(manifest: Manifest) -> str:
    name = (manifest.scene or {}).get("name")
    return f" ('{name}')" if name else ""


def scene_for_bundle(path: str | os.PathLike[str], force: bool = False) -> tuple[Any, str]:
    """The scene to render a bundle with when the user named none, and where it came from: the scene the
    bundle records (manifest ``scene.spec``, version 2), rebuilt and checked against its fingerprint, else
    the default builtin scene. A scene that cannot be rebuilt, or (unless ``force``) that is not the one the
    field was trained for, is refused in one line that says no scene was given and which one was used."""
    from photon_fields.runtime.scene.scene import DEFAULT_SCENE, builtin_scene, scene_from_dict

    manifest = read_manifest(path)
    recorded = manifest.scene or {}
    name = recorded.get("name") or "?"
    if recorded.get("spec") is not None:
        try:
            scene = scene_from_dict(recorded["spec"], what=f"{path} scene '{name}'")
        except InputError as err:
            raise InputError(str(path), f"no --scene given, and the scene the bundle records ('{name}') cannot be "
                             f"rebuilt: {err}; pass --scene") from None
        used, source = f"the scene the bundle records ('{name}')", "bundle"
    else:
        scene, used, source = builtin_scene(DEFAULT_SCENE), f"the default scene '{DEFAULT_SCENE}'", "default"
    if scene.fingerprint() != manifest.scene_fingerprint and not force:
        detail = mismatch_detail(scene.fingerprint_parts(), manifest.scene_parts)
        if source == "bundle":
            raise InputError(str(path), f"no --scene given, and {used} no longer rebuilds to the scene it was "
                             f"trained for: {detail}; pass --scene")
        raise InputError(str(path), f"no --scene given, so {used} was used; the bundle was trained for another "
                         f"scene{_trained_name(manifest)}: {detail}; pass --scene")
    return scene, source


def _check_file(bundle: Path, name: str, entry: dict[str, Any]) -> Path:
    path = bundle / name
    if not path.is_file():
        raise InputError(str(path), "missing (the manifest lists it)")
    size = path.stat().st_size
    if size != entry["bytes"]:
        kind = "truncated" if size < entry["bytes"] else "longer than the manifest says"
        raise InputError(str(path), f"{kind}: {size} bytes, the manifest says {entry['bytes']}")
    digest, _ = file_digest(path)
    if digest != entry["sha256"]:
        raise InputError(str(path), "checksum mismatch: sha256 differs from the manifest (corrupt or modified)")
    return path


def _load_tables(path: Path, manifest: Manifest) -> dict[str, np.ndarray]:
    what = str(path)
    if not zipfile.is_zipfile(path):
        # np.load would try the other formats, pickle last (and refuse it, with advice to unpickle).
        raise InputError(what, "not an .npz archive (no zip structure)")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(what, f"not a readable .npz: {exc}") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise InputError(what, "not an .npz archive")
    tables: dict[str, np.ndarray] = {}
    expected = list(table_shapes(manifest.config))  # the hash tables, and the surface grid for a field with it
    with z:
        names = sorted(z.files)
        if names != sorted(expected):
            # Unknown entries are refused by name, before anything is read from them.
            raise InputError(what, f"must hold exactly the arrays {expected}, found {names}")
        for name in expected:
            try:
                a = z[name]
            except ValueError as exc:  # object arrays: numpy refuses to unpickle with allow_pickle=False
                if "pickle" in str(exc).lower():
                    raise InputError(what, f"'{name}' is a pickled object array: refused (never unpickled)") from None
                raise InputError(what, f"'{name}' is not a readable array: {exc}") from None
            except (OSError, EOFError, zipfile.BadZipFile) as exc:
                raise InputError(what, f"'{name}' is not a readable array: {exc}") from None
            try:
                check_table(manifest, name, a.shape, a.dtype, what)
            except BundleError as err:
                raise InputError(err.what, err.problem) from None
            if name == SURFACE_ARRAY:  # int8, read as it is
                tables[name] = np.ascontiguousarray(a)
                continue
            if not np.all(np.isfinite(a)):
                raise InputError(what, f"'{name}' contains non-finite values")
            # numba has no float16 on the CPU: widen once (exact), and align rows to cache lines.
            tables[name] = aligned_table(np.ascontiguousarray(a, dtype=np.float32))
    return tables


def _check_onnx(path: Path, data: bytes, manifest: Manifest) -> Any:
    import onnx

    what = str(path)
    try:
        model = onnx.load_from_string(data)
    except Exception as exc:  # protobuf's DecodeError and friends
        raise InputError(what, f"not an ONNX model: {type(exc).__name__}: {exc}") from None
    for init in model.graph.initializer:
        if init.data_location == onnx.TensorProto.EXTERNAL:
            raise InputError(what, f"initializer '{init.name}' uses external data; a bundle's field.onnx must be "
                             "self-contained")
    try:
        onnx.checker.check_model(model, full_check=True)
    except (onnx.checker.ValidationError, onnx.shape_inference.InferenceError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(what, f"fails onnx.checker: {first}") from None
    init_names = {i.name for i in model.graph.initializer}
    inputs = [i for i in model.graph.input if i.name not in init_names]
    if [i.name for i in inputs] != [ONNX_INPUT]:
        raise InputError(what, f"must have one input '{ONNX_INPUT}', has {[i.name for i in inputs]}")
    if [o.name for o in model.graph.output] != [ONNX_OUTPUT]:
        raise InputError(what, f"must have one output '{ONNX_OUTPUT}', has {[o.name for o in model.graph.output]}")
    want = {"input": manifest.input_width, "output": manifest.config.output_dims}
    for kind, value in (("input", inputs[0]), ("output", model.graph.output[0])):
        tt = value.type.tensor_type
        if tt.elem_type != onnx.TensorProto.FLOAT:
            raise InputError(what, f"{kind} '{value.name}' must be float32, has element type "
                             f"{onnx.TensorProto.DataType.Name(tt.elem_type)}")
        dims = tt.shape.dim
        width = dims[1].dim_value if len(dims) == 2 and dims[1].HasField("dim_value") else None
        if len(dims) != 2 or dims[0].HasField("dim_value") or width is None:
            raise InputError(what, f"{kind} '{value.name}' must have shape (batch, {want[kind]}) with a dynamic "
                             "batch axis")
        if width != want[kind]:
            meaning = "the encodings' features + g" if kind == "input" else "RGB per light channel"
            raise InputError(what, f"{kind} width {width} does not match the manifest: {meaning} needs "
                             f"{want[kind]}")
    return model
