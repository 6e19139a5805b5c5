"""A trained photon field at render time: load a ``NAME.pfn`` bundle and query it, without torch.

``P(x, g, omega)`` of the paper (Sec. 3.1, Eq. 2; network of Sec. 3.4, Fig. 5) evaluated as Alg. 2's
indirect-light estimate needs it: both hash encodings (numba, :mod:`runtime.field.hashgrid`, bit-exact with
training's), the MLP in onnxruntime, Eq. 7 to decode. The bundle format is :mod:`photon_fields.models_spec.bundle`.

Python API::

    from photon_fields.runtime.field.field import PhotonField
    field = PhotonField.load("runs/vortex/field.pfn", threads=2)          # validates everything
    L = field.query(x, omega, g)          # x (N, 3) world, omega (N, 3) unit travel directions, g (N,) or scalar
    Lp = field.query_encoded(x, omega, g) # L' (Eq. 6 space), what the ONNX model outputs
    q = field.estimator()                 # runtime.wavefront.first_interaction.IndirectEstimator: (3, n) in and out
    print(field.timers)                   # encode (position, direction) / inference / decode seconds

``load(path, *, threads=None, precision="fp32", expected_fingerprint=None, force=False, chunk=..., ...,
expected_parts=None)``
----------------------------------------------------------------------------------------------------------
path : the bundle directory.
threads : worker threads for the hash encoding (numba, set around each query and restored) and for
    onnxruntime's intra-op pool; None: numba's current setting and all cores for onnxruntime.
precision : "fp32", the only one (the exact path: L' within 1e-5 of the torch model,
    tests/runtime/field/test_bundle.py).
    "int8" was removed and is refused in one line, and fp16 is not offered: see "Precision" below.
expected_fingerprint : the scene's :meth:`runtime.scene.scene.Scene.fingerprint`; a bundle trained for another
    scene is refused unless ``force`` (then ``field.scene_warning`` is the one-line warning to show, and
    ``describe()`` reports it).
expected_parts : the scene's :meth:`runtime.scene.scene.Scene.fingerprint_parts`: the refusal or warning then
    names what differs (volume, transfer function, lights), if the bundle records its parts (version 2).
chunk : queries per onnxruntime call (the encode buffer holds ``chunk`` rows; default :data:`DEFAULT_CHUNK`).
spinning : let onnxruntime's idle workers spin (default False, see "Threads").
pipeline : overlap the two halves: onnxruntime runs chunk k in a worker thread (``run`` releases the GIL)
    while numba encodes chunk k + 1 into a second buffer (default False, see "Threads"). Same results bit
    for bit; timers then add up to more than the wall time.

Every refusal is a one-line :class:`photon_fields.runtime.errors.InputError` naming the file and the problem: bundle or
file missing, manifest not JSON / failing the schema / another format / a newer version, a file whose size
or sha256 differs from the manifest (corrupt, truncated, replaced), a tables.npz with other arrays, another
shape or dtype, non-finite values or a pickled object array (refused, never unpickled), an ONNX model with
external data, failing ``onnx.checker``, or with an input width other than the encodings' features + 1,
and a scene fingerprint mismatch.

Query pipeline, per chunk of ``chunk`` queries, into one reused float32 buffer (chunk, W):
``normalize_position`` + position hash encoding into columns ``[0, Lp Fp)``; ``direction_input`` + direction
encoding into ``[Lp Fp, Lp Fp + Ld Fd)`` (``runtime.field.hashgrid.encode(out=buf, col=...)``: no concatenation
copy); g into the last column; ``InferenceSession.run`` on the buffer. Eq. 7 (``decode_radiance`` of
:mod:`photon_fields.models_spec.encoding`, the same function training's targets are checked with) runs once over the
whole result. ``field.timers`` accumulates seconds per stage over calls (``reset()`` clears them).

Measured (``bench/bench_field.py``, bench/README.md; this machine had another ~1 of its 2 cores busy
throughout, so the figures are contended and A/B comparisons were interleaved call by call)
-------------------------------------------------------------------------------------------------------
Where the time goes, cpu-preset architecture (8x4 / 6x2 encodings, 45 -> 64x3 -> 3), 2^18 random queries:
position encoding ~45-55 %, onnxruntime ~30-40 %, direction encoding ~10 %, decode and the float64
coordinate transforms ~5 %; about 1.0-1.5 CPU-seconds per million queries, 0.6-1.0 M queries/s wall.
The paper architecture (16x8 / 2^19 encodings, 257 -> 64x4 -> 3) costs 4-5 CPU-s per million, 0.2-0.25 M/s:
its encodings are about three quarters of it (random reads into 400 MB of tables). Loading validates every
byte: ~0.1 s for the cpu-preset bundle (6 MB), ~3 s for the paper's (407 MB: sha256, reading, the finite
check and the aligned copy).

Threads
-------
numba's workers and onnxruntime's pool alternate on the same cores, chunk after chunk. onnxruntime's
workers spin after each run by default and then steal the core the next numba kernel needs: with
spinning on, 0.62x the queries/s of ``allow_spinning = 0`` (interleaved A/B) and 1.8x the CPU time per
query, so spinning is off by default. Chunks of 2^12 .. 2^16 measured within +-5 % of each other; 2^14
keeps the paper architecture's buffer at 16 MB. ``pipeline=True`` measured equal to sequential here, as
it must with one core left to this process; it can only pay on idle cores, where encode and inference
each scale poorly from 1 to 2 threads (~1.3x) and could instead run side by side on one core each:
``pipeline=True, threads=1`` is the configuration to try there (``bench_field.py`` measures it).

Precision
---------
- fp16 MLP (float16 weights and activations in onnxruntime, casts at both ends): same speed as fp32
  end to end (0.66 vs 0.64 M/s) and for the MLP alone (1.04 vs 1.03 M/s at 2^14), ~1e-4 error: not offered.
  onnxruntime's x86 CPU kernels have no fast fp16 GEMM.
- fp16 *tables* (``pfn-train export --tables-dtype float16``): half the bundle size; the runtime widens
  them to float32 at load (numba has no float16 on the CPU), so speed is unchanged and the runtime still
  equals the torch model evaluated with the same rounded tables (within 1e-5 on L'); the rounding itself
  (relative 2^-11) moved L' by ~2e-4 on tables of magnitude 1 (tested bound 2e-3).
- int8 dynamic quantization of the MLP was offered until 0.1 and is refused now. onnxruntime's U8S8 kernels
  saturate int16 sums on x86 CPUs without VNNI (AVX2 only, AVX-512 without VNNI): on an AMD EPYC with AVX2
  it was off by 0.27 on L' (tested bound 2e-2, fine on VNNI and AMX machines). Its speed did not pay for an
  ISA-dependent error that no single machine can test: end to end 0.83x of fp32 on an Intel AMX machine,
  1.2x on an AMD EPYC with AVX-512 VNNI (the MLP is 30-40 % of a query and a query a small part of a
  frame). ``bench/bench_field.py`` still measures it (speed and error) for a future decision.
"""

from __future__ import annotations

import contextlib
import os
import time
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.bundle import (
    MANIFEST_FILE,
    MAX_MANIFEST_BYTES,
    ONNX_FILE,
    ONNX_INPUT,
    ONNX_OUTPUT,
    TABLE_ARRAYS,
    TABLES_FILE,
    BundleError,
    Manifest,
    check_table,
    file_digest,
    parse_manifest_bytes,
)
from photon_fields.models_spec.encoding import OUTPUT_CHANNELS, decode_radiance, direction_input, normalize_position
from photon_fields.models_spec.fingerprint import mismatch_detail
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.field.hashgrid import aligned_table, encode

#: Queries per onnxruntime call (bench/bench_field.py sweeps it: 2^14 keeps the encode buffer of the
#: paper architecture (257 floats per row, 16 MB) within reach of the caches, and larger chunks bought
#: nothing measurable).
DEFAULT_CHUNK = 1 << 14
PRECISIONS = ("fp32",)
#: Precisions that were offered once, with why they are refused now (module docstring, "Precision").
REMOVED_PRECISIONS = {"int8": "int8 was removed: onnxruntime's int8 kernels lose accuracy on CPUs without "
                              "VNNI and it was not faster; use fp32"}


@dataclass
class FieldTimers:
    """Seconds per query stage, accumulated over calls (``queries``: points evaluated)."""

    encode_position_s: float = 0.0
    encode_direction_s: float = 0.0
    inference_s: float = 0.0
    decode_s: float = 0.0
    queries: int = 0
    calls: int = 0

    def reset(self) -> None:
        for f in fields(self):
            setattr(self, f.name, type(getattr(self, f.name))(0))

    @property
    def total_s(self) -> float:
        return self.encode_position_s + self.encode_direction_s + self.inference_s + self.decode_s

    def to_dict(self) -> dict[str, float]:
        return {**{f.name: getattr(self, f.name) for f in fields(self)}, "total_s": self.total_s}


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
    with z:
        names = sorted(z.files)
        if names != sorted(TABLE_ARRAYS):
            # Unknown entries are refused by name, before anything is read from them.
            raise InputError(what, f"must hold exactly the arrays {list(TABLE_ARRAYS)}, found {names}")
        for name in TABLE_ARRAYS:
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
    want = {"input": manifest.input_width, "output": OUTPUT_CHANNELS}
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
            meaning = "the encodings' features + g" if kind == "input" else "RGB"
            raise InputError(what, f"{kind} width {width} does not match the manifest: {meaning} needs "
                             f"{want[kind]}")
    return model


def make_session(model_bytes: bytes, what: str, threads: int | None, spinning: bool) -> Any:
    """An onnxruntime CPU session for an MLP (spinning off unless asked, ``threads`` intra-op threads); a model
    onnxruntime refuses is one line naming ``what``."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 0 if threads is None else int(threads)
    so.inter_op_num_threads = 1  # one chain of MatMuls: nothing to run side by side
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.log_severity_level = 3  # errors only: no per-session warnings on stderr
    so.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
    try:
        return ort.InferenceSession(model_bytes, so, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types
        raise InputError(what, f"onnxruntime cannot load it: {str(exc).splitlines()[0] if str(exc) else exc}") from None


@contextlib.contextmanager
def _numba_threads(threads: int | None) -> Iterator[None]:
    if threads is None:
        yield
        return
    import numba

    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(previous)


class PhotonField:
    """A loaded bundle (see the module docstring). Not thread-safe: one encode buffer is reused per call."""

    def __init__(self, path: Path, manifest: Manifest, tables: dict[str, np.ndarray], session: Any, *,
                 threads: int | None, precision: str, chunk: int, spinning: bool, pipeline: bool = False) -> None:
        self.path = path
        self.manifest = manifest
        self.config = manifest.config
        self.bmin, self.bsize = manifest.bmin, manifest.bsize
        self.scene_fingerprint = manifest.scene_fingerprint
        #: Set by :meth:`load` when a bundle trained for another scene was forced: one line naming what
        #: differs (``"... lights differ (volume and transfer function match); L_i will be wrong"``).
        self.scene_warning: str | None = None
        self.position_table = tables["position"]
        self.direction_table = tables["direction"]
        self.session = session
        self.threads, self.precision, self.chunk, self.spinning = threads, precision, int(chunk), spinning
        self.pipeline = bool(pipeline)
        self.timers = FieldTimers()
        self._dir_col = self.config.position.output_dims
        self._buffers = [np.empty((0, self.config.input_dims), np.float32) for _ in range(2)]
        self._pool: Any = None

    # ------------------------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | os.PathLike[str], *, threads: int | None = None, precision: str = "fp32",
             expected_fingerprint: str | None = None, force: bool = False, chunk: int = DEFAULT_CHUNK,
             spinning: bool = False, pipeline: bool = False,
             expected_parts: dict[str, str] | None = None) -> PhotonField:
        """Load and validate a bundle (module docstring); one-line InputError on any problem."""
        bundle = Path(path)
        if precision in REMOVED_PRECISIONS:
            raise InputError("precision", REMOVED_PRECISIONS[precision])
        if precision not in PRECISIONS:
            raise InputError("precision", f"must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        if threads is not None:
            import numba

            if isinstance(threads, bool) or not isinstance(threads, int) or \
                    not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
                raise InputError("threads", f"must be an integer in [1, {numba.config.NUMBA_NUM_THREADS}], got "
                                 f"{threads!r}")
        if isinstance(chunk, bool) or not isinstance(chunk, int) or not 1 <= chunk <= 1 << 22:
            raise InputError("chunk", f"must be an integer in [1, {1 << 22}], got {chunk!r}")
        manifest = read_manifest(bundle)
        warning = None
        if expected_fingerprint is not None and manifest.scene_fingerprint != expected_fingerprint:
            other = f"another scene{_trained_name(manifest)}: {mismatch_detail(expected_parts, manifest.scene_parts)}"
            if not force:
                raise InputError(str(bundle), f"was trained for {other}; retrain, or force to use it anyway")
            warning = f"{bundle} was trained for {other}; L_i will be wrong"
        onnx_path = _check_file(bundle, ONNX_FILE, manifest.files[ONNX_FILE])
        tables_path = _check_file(bundle, TABLES_FILE, manifest.files[TABLES_FILE])
        data = onnx_path.read_bytes()
        _check_onnx(onnx_path, data, manifest)
        tables = _load_tables(tables_path, manifest)
        session = make_session(data, str(onnx_path), threads, spinning)
        field = cls(bundle, manifest, tables, session, threads=threads, precision=precision, chunk=chunk,
                    spinning=spinning, pipeline=pipeline)
        field.scene_warning = warning
        return field

    # ------------------------------------------------------------------------------------------------
    @property
    def input_width(self) -> int:
        return self.config.input_dims

    def _inputs(self, x: Any, omega: Any, g: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x = np.asarray(x)
        omega = np.asarray(omega)
        if x.ndim != 2 or x.shape[1] != 3:
            raise InputError("query x", f"must have shape (N, 3), got {x.shape}")
        n = x.shape[0]
        if omega.shape != (n, 3):
            raise InputError("query omega", f"must have shape ({n}, 3) like x, got {omega.shape}")
        ga = np.asarray(g, dtype=np.float32)
        if ga.ndim == 0:
            ga = np.full(n, ga, np.float32)
        elif ga.shape != (n,):
            raise InputError("query g", f"must be a scalar or have shape ({n},), got {ga.shape}")
        if not np.all(np.isfinite(ga)):
            raise InputError("query g", "must be finite")
        return x, omega, ga

    def _buf(self, m: int, k: int = 0) -> np.ndarray:
        if self._buffers[k].shape[0] < m:
            self._buffers[k] = np.empty((m, self.input_width), np.float32)
        return self._buffers[k][:m]

    def encode_inputs(self, x: Any, omega: Any, g: Any) -> np.ndarray:
        """The MLP input (N, W) float32 for N queries (one buffer, no chunking; for tests and inspection)."""
        x, omega, ga = self._inputs(x, omega, g)
        out = np.empty((x.shape[0], self.input_width), np.float32)
        self._encode_into(out, x, omega, ga)
        return out

    def _encode_into(self, buf: np.ndarray, x: np.ndarray, omega: np.ndarray, ga: np.ndarray) -> None:
        cfg, t = self.config, self.timers
        t0 = time.perf_counter()
        try:
            encode(cfg.position, self.position_table, normalize_position(x, self.bmin, self.bsize), out=buf)
            t1 = time.perf_counter()
            encode(cfg.direction, self.direction_table, direction_input(omega), out=buf, col=self._dir_col)
        except ValueError as exc:  # non-finite or absurdly far positions / directions
            raise InputError("query", str(exc)) from None
        t2 = time.perf_counter()
        buf[:, -1] = ga
        t.encode_position_s += t1 - t0
        t.encode_direction_s += t2 - t1

    def query_encoded(self, x: Any, omega: Any, g: Any) -> np.ndarray:
        """L' (Eq. 6 space, the ONNX output) as float32 (N, 3) for world positions x (N, 3), unit camera-ray
        travel directions omega (N, 3) and g (N,) or a scalar."""
        x, omega, ga = self._inputs(x, omega, g)
        n = x.shape[0]
        out = np.empty((n, OUTPUT_CHANNELS), np.float32)
        t = self.timers
        with _numba_threads(self.threads):
            if self.pipeline and n > self.chunk:
                self._pipelined(out, x, omega, ga)
            else:
                for a in range(0, n, self.chunk):
                    b = min(n, a + self.chunk)
                    buf = self._buf(b - a)
                    self._encode_into(buf, x[a:b], omega[a:b], ga[a:b])
                    self._infer(buf, out, a, b)
        t.queries += n
        t.calls += 1
        return out

    def _infer(self, buf: np.ndarray, out: np.ndarray, a: int, b: int) -> None:
        t0 = time.perf_counter()
        out[a:b] = self.session.run([ONNX_OUTPUT], {ONNX_INPUT: buf})[0]
        self.timers.inference_s += time.perf_counter() - t0

    def _pipelined(self, out: np.ndarray, x: np.ndarray, omega: np.ndarray, ga: np.ndarray) -> None:
        """Encode chunk k + 1 on this thread (numba) while a worker thread runs onnxruntime on chunk k
        (``run`` releases the GIL), with two encode buffers in turn. Buffer k % 2 is reused by chunk k + 2
        only after chunk k's inference has been waited for, before chunk k + 1 was submitted."""
        if self._pool is None:
            from concurrent.futures import ThreadPoolExecutor

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pfn-onnxruntime")
        n = x.shape[0]
        pending = None
        try:
            for k, a in enumerate(range(0, n, self.chunk)):
                b = min(n, a + self.chunk)
                buf = self._buf(b - a, k % 2)
                self._encode_into(buf, x[a:b], omega[a:b], ga[a:b])
                if pending is not None:
                    pending.result()
                pending = self._pool.submit(self._infer, buf, out, a, b)
        finally:
            if pending is not None:
                pending.result()  # never leave a run writing into a buffer the next call reuses

    def query(self, x: Any, omega: Any, g: Any) -> np.ndarray:
        """Radiance Q(x, omega, g) float32 (N, 3): :meth:`query_encoded` decoded by Eq. 7 (psi of the bundle)."""
        Lp = self.query_encoded(x, omega, g)
        t0 = time.perf_counter()
        L = decode_radiance(Lp, self.config.psi)
        self.timers.decode_s += time.perf_counter() - t0
        return L

    def estimator(self) -> FieldEstimator:
        """This field as the renderer's :class:`photon_fields.runtime.wavefront.first_interaction.IndirectEstimator`."""
        return FieldEstimator(self)

    def describe(self) -> dict[str, Any]:
        """What was loaded (for reports)."""
        return {"path": str(self.path), "precision": self.precision, "threads": self.threads, "chunk": self.chunk,
                "spinning": self.spinning, "pipeline": self.pipeline, "input_width": self.input_width,
                "field": self.config.to_dict(), "training": self.manifest.training,
                "scene_fingerprint": self.scene_fingerprint,
                "scene_parts": self.manifest.scene_parts, "trained_for": (self.manifest.scene or {}).get("name"),
                "scene_warning": self.scene_warning}


class FieldEstimator:
    """Q(x, d, g) from a photon field (Alg. 2's network query): ``x``, ``d`` (3, n) -> float32 (3, n)."""

    def __init__(self, field: PhotonField) -> None:
        self.field = field

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        return np.ascontiguousarray(self.field.query(np.asarray(x).T, np.asarray(d).T, g).T)
