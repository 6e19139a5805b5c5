"""runtime/numba_inlining.py: numba's inliner patched to copy a scope once per IR, in place before our kernels compile,
and compiling kernels that compute the same numbers as numba's own inliner."""

from __future__ import annotations

import ast
import inspect
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2]


def _module_name(path: Path) -> str:
    return "photon_fields." + ".".join(path.relative_to(PACKAGE).with_suffix("").parts)


def _imports(tree: ast.Module) -> set[str]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("photon_fields."):
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.startswith("photon_fields."))
    return out


def _calls_install(tree: ast.Module) -> bool:
    return any(isinstance(n, ast.Expr) and isinstance(n.value, ast.Call) and isinstance(n.value.func, ast.Name)
               and n.value.func.id == "install" for n in tree.body)


def test_every_module_with_an_inlined_kernel_installs_the_patch_at_import() -> None:
    """A module defining an ``inline="always"`` kernel calls ``install()`` at import, or imports one that does (at
    any depth): so no kernel inlining ours compiles before the patch is in place."""
    sources = {_module_name(p): p.read_text() for p in (PACKAGE / "runtime").rglob("*.py")}
    trees = {name: ast.parse(source) for name, source in sources.items()}
    covered: dict[str, bool] = {}

    def installs(name: str, seen: frozenset[str] = frozenset()) -> bool:
        if name not in covered:
            tree = trees.get(name)
            covered[name] = tree is not None and (_calls_install(tree) or any(
                installs(m, seen | {name}) for m in _imports(tree) if m not in seen and m != name))
        return covered[name]

    with_kernels = [n for n, s in sources.items() if 'inline="always"' in s and not n.endswith(".numba_inlining")]
    assert len(with_kernels) > 20, with_kernels
    missing = sorted(n for n in with_kernels if not installs(n))
    assert not missing, f"modules with inline kernels that do not install runtime/numba_inlining.py's patch: {missing}"


def test_the_patch_applies_to_this_numba() -> None:
    from numba.core import inline_closurecall

    from photon_fields.runtime import numba_inlining

    worker = inline_closurecall.InlineWorker
    source = inspect.getsource(getattr(worker.inline_ir, "__wrapped__", worker.inline_ir))
    if numba_inlining._EXPECTED not in source:
        pytest.skip("this numba copies inlined IR differently: the patch leaves it alone (nothing to test)")
    assert numba_inlining.install()
    assert getattr(worker.inline_ir, "__wrapped__", None) is not None


_RUN = r"""
import json, sys
import numpy as np
from photon_fields.runtime import numba_inlining
from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.transport.rng import stream_states
from photon_fields.runtime.transport.tracking import ratio_track_batch
m = builtin_scene("blobs").medium()
rng = np.random.default_rng(1)
n = 4000
o = m.bmin[:, None] + m.bsize[:, None] * rng.random((3, n))
d = rng.normal(size=(3, n))
d /= np.linalg.norm(d, axis=0)
out = ratio_track_batch(m, o, d, np.zeros(n), np.full(n, 10.0), stream_states(3, 0, n), 0.3, 2.0)
json.dump({"patched": numba_inlining._installed, "mean": float(out.mean()), "hex": out.tobytes().hex()}, sys.stdout)
"""


def test_kernels_compiled_with_the_patch_compute_what_numbas_own_inliner_gives(tmp_path: Path) -> None:
    """The ratio-tracking walk (``tracking._track`` and the ~20 helpers it inlines), compiled cold with and without
    the patch in fresh processes: the same numbers, bit for bit."""
    runs = {}
    for flag in ("1", "0"):
        env = {**os.environ, "PFN_NUMBA_INLINE_COPY": flag, "NUMBA_CACHE_DIR": str(tmp_path / f"cache{flag}")}
        out = subprocess.run([sys.executable, "-c", _RUN], env=env, check=True, capture_output=True, text=True,
                             timeout=900)
        runs[flag] = json.loads(out.stdout)
    assert runs["0"]["patched"] is False and 0.0 < runs["1"]["mean"] < 1.0
    assert runs["1"]["hex"] == runs["0"]["hex"]
