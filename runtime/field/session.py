"""The onnxruntime CPU session that runs a field's MLP.

Spinning is off unless asked: numba's workers and onnxruntime's pool alternate on the same cores chunk after
chunk, and onnxruntime's workers spin after each run by default, stealing the core the next numba kernel
needs (bench/README.md, ``bench_field.py``, has the measurements). One chain of MatMuls has nothing to run
side by side, so the inter-op pool has one thread.
"""

from __future__ import annotations

from typing import Any

from photon_fields.runtime.errors import InputError


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
