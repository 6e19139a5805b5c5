"""What the resident server loads before its first job: numba's kernels and the modules a render imports.

A fresh process pays for numba's typing context and each kernel's cache lookup at its first call (bench/README.md,
``bench_cli_startup.py``); the server pays once, in the background right after it starts listening (jobs that
arrive meanwhile wait their turn). :func:`warm_up` renders 8x8 pixels, 1 sample, of the builtin ``blobs`` scene with
``pfn-render``'s own main for the path tracer and the ray marcher (the scene, the kernels, the EXR / PNG / JSON
writers), runs the neural renderer's kernels with a stand-in for the field (no bundle is at hand: the field's
own cost is loading its bundle, which every job does anyway), hash-encodes a few points with the encoders of the
default field's grids, and runs a tiny onnxruntime session. The photon-map and PVRT renderers need their
inputs: their first job loads their kernels, and the jobs after it find them loaded.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
from typing import Any

#: The image every warm-up render makes: tiny, so that it takes well under a second once the kernels are loaded.
WARM_ARGS = ["--scene", "blobs", "--size", "8x8", "--spp", "1", "--quiet"]


def _no_field(x: Any, d: Any, g: float) -> Any:
    """The neural renderer's estimator (float32 (3, n), as a photon field's) with nothing in it."""
    import numpy as np

    return np.zeros((3, np.asarray(x).shape[1]), np.float32)


def warm_up() -> list[str]:
    """Load the kernels (module docstring); what was warmed, in words. Prints nothing."""
    from photon_fields.runtime.cli.render import _main

    done = []
    with tempfile.TemporaryDirectory(prefix="pfn-warm-") as folder, \
            contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        for method in ("pt", "raymarch"):
            if _main([*WARM_ARGS, "--method", method, "--out", os.path.join(folder, f"{method}.exr")]) == 0:
                done.append(method)
        _warm_neural()
        done.append("field kernels")
    return done


def _warm_neural() -> None:
    import numpy as np

    from photon_fields.models_spec.hashgrid import HashGridConfig, total_table_rows
    from photon_fields.runtime.field.hashgrid import encode
    from photon_fields.runtime.renderers.neural import render_neural
    from photon_fields.runtime.scene.scene import builtin_scene

    scene = builtin_scene("blobs").with_overrides(width=8, height=8)
    render_neural(scene, _no_field, spp=1, seed=0, progress=False)
    rng = np.random.default_rng(0)
    # The grids of the default (cpu) field: 3-D positions with 4 features, 2-D directions with 2 (models_spec).
    for cfg in (HashGridConfig(3, 2, 4, 8, 4, 1.5), HashGridConfig(2, 2, 2, 8, 4, 1.5)):
        table = rng.random((total_table_rows(cfg), cfg.features), dtype=np.float32)
        encode(cfg, table, rng.random((64, cfg.dims), dtype=np.float32))
    _warm_inference()


def _warm_inference() -> None:
    """One onnxruntime session run, of a 4 -> 3 MatMul: the first session of a process sets up onnxruntime itself
    (~25 ms of the first field job here)."""
    import numpy as np
    from onnx import TensorProto, helper

    from photon_fields.runtime.field.field import PhotonField  # noqa: F401  (imported for the first field job)
    from photon_fields.runtime.field.session import make_session

    weights = helper.make_tensor("W", TensorProto.FLOAT, [4, 3], [0.0] * 12)
    graph = helper.make_graph([helper.make_node("MatMul", ["x", "W"], ["y"])], "warm_up",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", 4])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["n", 3])], [weights])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    session = make_session(model.SerializeToString(), "warm-up model", None, False)
    session.run(None, {"x": np.zeros((8, 4), np.float32)})
