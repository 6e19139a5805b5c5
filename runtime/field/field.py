"""A trained photon field at render time: load a ``NAME.pfn`` bundle and query it, without torch.

``P(x, g, omega)`` of the paper (Sec. 3.1, Eq. 2; network of Sec. 3.4, Fig. 5) evaluated as Alg. 2's
indirect-light estimate needs it: both hash encodings (numba, :mod:`photon_fields.runtime.field.hashgrid`,
bit-exact with training's), the MLP in onnxruntime (:mod:`photon_fields.runtime.field.session`), Eq. 7 to
decode. The bundle is read and validated by :mod:`photon_fields.runtime.field.bundle_reader`; its format is
:mod:`photon_fields.models_spec.bundle`.

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
    tests/runtime/field/test_bundle.py). "int8" was removed and is refused in one line: onnxruntime's
    int8 kernels lose accuracy on CPUs without VNNI, an error no single machine can test. fp16 is not
    offered: onnxruntime's x86 CPU kernels have no fast fp16 GEMM. fp16 *tables* are a bundle option
    (``pfn-train export --tables-dtype float16``): widened to float32 at load, since numba has no float16
    on the CPU.
expected_fingerprint : the scene's :meth:`photon_fields.runtime.scene.scene.Scene.fingerprint`; a bundle trained
    for another scene is refused unless ``force`` (then ``field.scene_warning`` is the one-line warning to
    show, and ``describe()`` reports it).
expected_parts : the scene's :meth:`photon_fields.runtime.scene.scene.Scene.fingerprint_parts`: the refusal or
    warning then names what differs (volume, transfer function, lights), if the bundle records its parts.
chunk : queries per onnxruntime call (the encode buffer holds ``chunk`` rows; default :data:`DEFAULT_CHUNK`).
spinning : let onnxruntime's idle workers spin (default False: :mod:`photon_fields.runtime.field.session`).
pipeline : overlap the two halves: onnxruntime runs chunk k in a worker thread (``run`` releases the GIL)
    while numba encodes chunk k + 1 into a second buffer (default False). Same results bit for bit; timers
    then add up to more than the wall time. It can only pay on idle cores, where encoding and inference
    could run side by side on one core each (``pipeline=True, threads=1``).

Query pipeline, per chunk of ``chunk`` queries, into one reused float32 buffer (chunk, W):
the normalized position + position hash encoding into columns ``[0, Lp Fp)``; ``direction_input`` + direction
encoding into ``[Lp Fp, Lp Fp + Ld Fd)`` (``runtime.field.hashgrid.encode(out=buf,
col=...)``: no concatenation copy); those columns times g where the direction gain says so, and the phase features
into the last columns (numba loops without numpy's temporaries, :mod:`photon_fields.runtime.field.inputs`, equal to
:mod:`photon_fields.models_spec.encoding`'s functions bit for bit); for a field with the surface input its two
columns last (``surface_rows``, from the bundle's ``surface`` grid); ``InferenceSession.run`` on the buffer. A rendered
frame asks with one g: its gain and phase-feature row are computed once per g, and the two reused encode buffers keep
their phase columns while they hold that g's row for the rows a chunk uses (nothing else writes those columns; any
other g, more rows or per-query g write them again). The
direction timer includes the gains, the phase features and the surface columns. Eq. 7 (``decode_radiance`` of
:mod:`photon_fields.models_spec.encoding`, the same function training's targets are checked with) runs once over the
whole result. ``field.timers`` accumulates seconds per stage over calls (``reset()`` clears them). Where the
time goes, and the measurements behind each default, are in bench/README.md (``bench_field.py``).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.models_spec.bundle import ONNX_INPUT, ONNX_OUTPUT, SURFACE_ARRAY, Manifest
from photon_fields.models_spec.encoding import (
    OUTPUT_CHANNELS,
    decode_radiance,
    direction_gains,
    direction_input,
    phase_features,
)
from photon_fields.runtime.errors import InputError
from photon_fields.runtime.field.bundle_reader import read_bundle
from photon_fields.runtime.field.hashgrid import encode
from photon_fields.runtime.field.inputs import finish_rows, normalized_positions, surface_rows
from photon_fields.runtime.field.outputs import decode_lights
from photon_fields.runtime.field.session import make_session
from photon_fields.runtime.scene.light_rescale import rescale_note
from photon_fields.runtime.threads import check_threads, numba_threads

#: Queries per onnxruntime call: small enough that the paper architecture's encode buffer (257 floats a row)
#: stays near the caches, large enough that per-call overhead vanishes (``bench/bench_field.py`` sweeps it).
DEFAULT_CHUNK = 1 << 14
PRECISIONS = ("fp32",)
#: Precisions that were offered once, with why they are refused now (module docstring).
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
        #: Set by :meth:`load` when the scene's lights are the trained ones with their flux rescaled
        #: (:mod:`photon_fields.runtime.scene.light_rescale`): the RGB factor :meth:`query` applies ((3,), or (L, 3)
        #: one per light for a field with ``light_channels`` L), and a line saying so.
        self.light_scale: np.ndarray | None = None
        self.light_note: str | None = None
        self.position_table = tables["position"]
        self.direction_table = tables["direction"]
        #: The surface input's grid (int8, :mod:`photon_fields.models_spec.surface`), or None for a field without it.
        self.surface_grid: np.ndarray | None = tables.get(SURFACE_ARRAY)
        self.session = session
        self.threads, self.precision, self.chunk, self.spinning = threads, precision, int(chunk), spinning
        self.pipeline = bool(pipeline)
        self.timers = FieldTimers()
        self._dir_col = self.config.position.output_dims
        self._phase_col = self._dir_col + self.config.direction.output_dims
        self._surface_col = self._phase_col + self.config.phase_dims
        self._buffers = [np.empty((0, self.config.input_dims), np.float32) for _ in range(2)]
        #: Per encode buffer, (g, rows) whose phase columns already hold that g's features (None: not known); g as
        #: its float32's bytes, so that -0.0 and 0.0 (whose features differ in sign) are two values.
        self._phase_rows: list[tuple[bytes, int] | None] = [None, None]
        #: The last frame g's direction gains and phase-feature row: (g's bytes, gains, phase).
        self._frame_g: tuple[bytes, np.ndarray | None, np.ndarray] | None = None
        self._pool: Any = None

    # ------------------------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | os.PathLike[str], *, threads: int | None = None, precision: str = "fp32",
             expected_fingerprint: str | None = None, force: bool = False, chunk: int = DEFAULT_CHUNK,
             spinning: bool = False, pipeline: bool = False,
             expected_parts: dict[str, str] | None = None,
             expected_lights: list[dict[str, Any]] | None = None) -> PhotonField:
        """Load and validate a bundle (module docstring); one-line InputError on any problem. ``expected_lights``
        (the scene's lights as :func:`photon_fields.runtime.scene.lights.light_identity` dicts): a bundle whose
        lights differ from them only by a common flux factor is no mismatch; :meth:`query` then rescales
        (``light_scale``, ``light_note``)."""
        if precision in REMOVED_PRECISIONS:
            raise InputError("precision", REMOVED_PRECISIONS[precision])
        if precision not in PRECISIONS:
            raise InputError("precision", f"must be one of {', '.join(PRECISIONS)}, got {precision!r}")
        check_threads(threads, "threads")
        if isinstance(chunk, bool) or not isinstance(chunk, int) or not 1 <= chunk <= 1 << 22:
            raise InputError("chunk", f"must be an integer in [1, {1 << 22}], got {chunk!r}")
        contents = read_bundle(path, expected_fingerprint=expected_fingerprint, expected_parts=expected_parts,
                               force=force, expected_lights=expected_lights)
        session = make_session(contents.onnx_bytes, str(contents.onnx_path), threads, spinning)
        field = cls(contents.path, contents.manifest, contents.tables, session, threads=threads, precision=precision,
                    chunk=chunk, spinning=spinning, pipeline=pipeline)
        field.scene_warning = contents.scene_warning
        if contents.light_scale is not None:
            field.light_scale = contents.light_scale.astype(np.float32)
            field.light_note = rescale_note(contents.light_scale)
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
            self._phase_rows[k] = None
        return self._buffers[k][:m]

    def encode_inputs(self, x: Any, omega: Any, g: Any) -> np.ndarray:
        """The MLP input (N, W) float32 for N queries (one buffer, no chunking; for tests and inspection)."""
        x, omega, ga = self._inputs(x, omega, g)
        out = np.empty((x.shape[0], self.input_width), np.float32)
        self._encode_into(out, x, omega, ga)
        return out

    def _encode_into(self, buf: np.ndarray, x: np.ndarray, omega: np.ndarray, ga: np.ndarray,
                     k: int | None = None) -> None:
        """The MLP input rows of x, omega, g into ``buf``; ``k``: which of the reused encode buffers it is (None: a
        buffer of the caller's, every column written)."""
        cfg, t = self.config, self.timers
        one_g = ga.shape[0] >= 1 and bool((ga == ga[0]).all())
        gain = 1.0
        if one_g:
            # One g for the chunk (a rendered frame): one gain, applied as the direction encoder stores its features,
            # and one row of phase features for every row, both computed once per g; a reused buffer whose phase
            # columns already hold that row (nothing else writes them) keeps them.
            g0 = ga[:1].tobytes()
            if self._frame_g is None or self._frame_g[0] != g0:
                one = ga[:1]
                self._frame_g = (g0, direction_gains(one, cfg.direction_gain),
                                 phase_features(one, cfg.phases, cfg.phase_encoding))
            _, gains, phase = self._frame_g
            gain = 1.0 if gains is None else float(gains[0, 0])
        t0 = time.perf_counter()
        try:
            u = normalized_positions(x, self.bmin, self.bsize)
            encode(cfg.position, self.position_table, u, out=buf)
            t1 = time.perf_counter()
            encode(cfg.direction, self.direction_table, direction_input(omega), out=buf, col=self._dir_col, gain=gain)
        except ValueError as exc:  # non-finite or absurdly far positions / directions
            raise InputError("query", str(exc)) from None
        if one_g:
            rows = buf.shape[0]
            held = self._phase_rows[k] if k is not None else None
            keep = held is not None and held[0] == g0 and held[1] >= rows
            finish_rows(buf, self._dir_col, self._phase_col, None, None if keep else phase, self._surface_col)
            if k is not None and not keep:
                self._phase_rows[k] = (g0, rows)
        else:
            finish_rows(buf, self._dir_col, self._phase_col, direction_gains(ga, cfg.direction_gain),
                        phase_features(ga, cfg.phases, cfg.phase_encoding), self._surface_col)
            if k is not None:
                self._phase_rows[k] = None
        if self.surface_grid is not None:
            surface_rows(buf, self._surface_col, u, omega, ga[:1] if one_g else ga, self.surface_grid)
        t2 = time.perf_counter()
        t.encode_position_s += t1 - t0
        t.encode_direction_s += t2 - t1

    @property
    def light_channels(self) -> int:
        """Lights whose parts the field outputs apart (1: one RGB output for all lights together)."""
        return self.config.light_channels

    def query_encoded(self, x: Any, omega: Any, g: Any) -> np.ndarray:
        """L' (Eq. 6 space, the ONNX output) as float32 (N, 3 C) for world positions x (N, 3), unit camera-ray
        travel directions omega (N, 3) and g (N,) or a scalar; C = :attr:`light_channels`."""
        x, omega, ga = self._inputs(x, omega, g)
        n = x.shape[0]
        out = np.empty((n, self.config.output_dims), np.float32)
        t = self.timers
        with numba_threads(self.threads):
            if self.pipeline and n > self.chunk:
                self._pipelined(out, x, omega, ga)
            else:
                for a in range(0, n, self.chunk):
                    b = min(n, a + self.chunk)
                    buf = self._buf(b - a)
                    self._encode_into(buf, x[a:b], omega[a:b], ga[a:b], 0)
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
                self._encode_into(buf, x[a:b], omega[a:b], ga[a:b], k % 2)
                if pending is not None:
                    pending.result()
                pending = self._pool.submit(self._infer, buf, out, a, b)
        finally:
            if pending is not None:
                pending.result()  # never leave a run writing into a buffer the next call reuses

    def query(self, x: Any, omega: Any, g: Any, light_scale: np.ndarray | None = None) -> np.ndarray:
        """Radiance Q(x, omega, g) float32 (N, 3): :meth:`query_encoded` decoded by Eq. 7 (psi of the bundle), times
        the field's ``light_scale`` (set at load when the scene's lights are the trained ones rescaled) and the
        argument ``light_scale`` on top of it (a further edit of those lights, the viewer's): each RGB (3,), or one
        factor per light (C, 3) for a field with C > 1 light channels; with C > 1 the lights' parts are summed,
        each times its factor."""
        Lp = self.query_encoded(x, omega, g)
        t0 = time.perf_counter()
        scale = self.light_scale
        if light_scale is not None:
            edit = np.asarray(light_scale, np.float32)
            scale = edit if scale is None else scale * edit
        L = decode_lights(Lp, self.config.psi, self.light_channels, scale)
        self.timers.decode_s += time.perf_counter() - t0
        return L

    def query_lights(self, x: Any, omega: Any, g: Any) -> np.ndarray:
        """Each light's part of Q float32 (N, C, 3) as trained (no ``light_scale``), C = :attr:`light_channels`."""
        L = decode_radiance(self.query_encoded(x, omega, g), self.config.psi)
        return L.reshape(L.shape[0], self.light_channels, OUTPUT_CHANNELS)

    def estimator(self, light_scale: np.ndarray | None = None) -> FieldEstimator:
        """This field as the renderer's :class:`photon_fields.runtime.wavefront.first_interaction.IndirectEstimator`
        (``light_scale``: as :meth:`query`'s)."""
        return FieldEstimator(self, light_scale)

    def describe(self) -> dict[str, Any]:
        """What was loaded (for reports)."""
        return {"path": str(self.path), "precision": self.precision, "threads": self.threads, "chunk": self.chunk,
                "spinning": self.spinning, "pipeline": self.pipeline, "input_width": self.input_width,
                "field": self.config.to_dict(), "training": self.manifest.training,
                "scene_fingerprint": self.scene_fingerprint,
                "scene_parts": self.manifest.scene_parts, "trained_for": (self.manifest.scene or {}).get("name"),
                "scene_warning": self.scene_warning,
                "light_channels": self.light_channels,
                "light_scale": None if self.light_scale is None else self.light_scale.tolist(),
                "light_note": self.light_note}


class FieldEstimator:
    """Q(x, d, g) from a photon field (Alg. 2's network query): ``x``, ``d`` (3, n) -> float32 (3, n); with
    ``light_scale`` (:meth:`PhotonField.query`'s) on top of the field's own."""

    def __init__(self, field: PhotonField, light_scale: np.ndarray | None = None) -> None:
        self.field, self.light_scale = field, light_scale

    def __call__(self, x: np.ndarray, d: np.ndarray, g: float) -> np.ndarray:
        return np.ascontiguousarray(self.field.query(np.asarray(x).T, np.asarray(d).T, g, self.light_scale).T)
