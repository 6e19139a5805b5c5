"""runtime/borrowed.py: a borrowed array is the same memory without reference counting, and the task kernels of our
parallel loops borrow the medium they walk."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
from numba import njit

from photon_fields.runtime.borrowed import borrowed
from photon_fields.runtime.numba_inlining import install
from photon_fields.runtime.scene.scene import builtin_scene
from photon_fields.runtime.transport.medium import Medium, borrowed_medium
from photon_fields.runtime.transport.tracking import _RATIO, _track

install()
ROOT = Path(__file__).resolve().parents[2]
KERNEL_TREES = (ROOT / "runtime", ROOT / "train")


@njit(cache=True)
def _write_through(a: np.ndarray, value: float) -> tuple[int, int, int, int]:
    b = borrowed(a)
    for i in range(b.shape[0]):
        for j in range(b.shape[1]):
            b[i, j] = value * (i * b.shape[1] + j)
    return b.shape[0], b.shape[1], b.strides[0], b.strides[1]


def test_a_borrowed_array_is_its_owners_memory_shape_and_strides() -> None:
    """Writes through the borrowed array land in the owner, C-contiguous or strided (a column slice)."""
    for base, view in ((np.zeros((5, 8)), lambda b: b), (np.zeros((5, 8)), lambda b: b[1:, ::3])):
        a = view(base)
        shape0, shape1, stride0, stride1 = _write_through(a, 2.0)
        assert (shape0, shape1) == a.shape and (stride0, stride1) == a.strides
        assert np.array_equal(a, 2.0 * np.arange(a.size, dtype=float).reshape(a.shape))
    untouched = np.ones(base.shape, bool)
    untouched[1:, ::3] = False
    assert np.all(base[untouched] == 0.0)  # the strided view wrote its own elements only


def _ratio_walks(m: Medium, o: np.ndarray, d: np.ndarray, states: np.ndarray, out: np.ndarray) -> None:
    for i in range(o.shape[1]):
        _, _, out[i], states[i] = _track(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], 0.0, 2.0,
                                         states[i], _RATIO, 0.0, 0.3, 2.0)


def _ratio_walks_borrowing(m: Medium, o: np.ndarray, d: np.ndarray, states: np.ndarray, out: np.ndarray) -> None:
    m = borrowed_medium(m)
    for i in range(o.shape[1]):
        _, _, out[i], states[i] = _track(m, o[0, i], o[1, i], o[2, i], d[0, i], d[1, i], d[2, i], 0.0, 2.0,
                                         states[i], _RATIO, 0.0, 0.3, 2.0)


def _refcount_calls(fn, *args) -> int:  # noqa: ANN001 (a plain Python function, compiled here without a cache)
    """NRT_incref / NRT_decref calls left in the optimized LLVM IR of ``fn`` compiled for ``args``."""
    kernel = njit(fn)
    kernel(*args)
    (cres,) = kernel.overloads.values()
    ir = cres.library.get_llvm_str()
    body = re.search(r"\ndefine [^\n]*@" + re.escape(cres.fndesc.mangled_name) + r"\(.*?\n}\n", ir, re.S).group(0)
    return len(re.findall(r"call void @NRT_(?:in|de)cref", body))


def test_borrowing_takes_the_reference_counting_out_of_the_inlined_walk() -> None:
    """Ratio-tracking walks (tracking._track inlined, its DDA with early exits) over the blobs medium: the plain loop
    keeps dozens of refcount calls in its body (the premise: numba's pruning leaves the medium's arrays counted up and
    down around the inlined helpers), the borrowing one only its arguments' at entry; the same transmittances, bit
    for bit."""
    m = builtin_scene("blobs").medium()
    rng = np.random.default_rng(1)
    o = rng.uniform(0.3, 0.7, (3, 64))
    d = rng.normal(size=(3, 64))
    d /= np.linalg.norm(d, axis=0)
    outs = []
    counts = []
    for fn in (_ratio_walks, _ratio_walks_borrowing):
        states, out = np.arange(64, dtype=np.uint64), np.empty(64)
        counts.append(_refcount_calls(fn, m, o, d, states, out))
        outs.append(out)
    assert np.array_equal(outs[0], outs[1])
    plain, borrowing = counts
    assert plain >= 32, counts  # two or more rounds of the medium's eight arrays, up and down
    assert borrowing <= 12, counts  # the four array arguments' references at entry and exit


def _decorator_kw(fn: ast.FunctionDef) -> dict[str, object]:
    for dec in fn.decorator_list:
        if isinstance(dec, ast.Call) and getattr(dec.func, "id", None) == "njit":
            return {k.arg: getattr(k.value, "value", None) for k in dec.keywords}
        if getattr(dec, "id", None) == "njit":
            return {}
    return {"not njit": True}


def _takes_medium(fn: ast.FunctionDef) -> bool:
    return any(isinstance(a.annotation, ast.Name) and a.annotation.id == "Medium" for a in fn.args.args)


def test_every_task_kernel_of_a_parallel_loop_borrows_its_medium() -> None:
    """A serial kernel called inside a ``prange`` loop with the medium (the walks' task kernels) borrows it at its
    start (``borrowed_medium``): else each inlined walk step counts the medium's eight arrays up and down."""
    checked, missing = [], []
    for path in sorted(p for tree in KERNEL_TREES for p in tree.rglob("*.py")):
        tree = ast.parse(path.read_text())
        functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
        for fn in functions.values():
            if not _decorator_kw(fn).get("parallel"):
                continue
            for loop in ast.walk(fn):
                if not (isinstance(loop, ast.For) and isinstance(loop.iter, ast.Call)
                        and getattr(loop.iter.func, "id", None) == "prange"):
                    continue
                for call in (c for stmt in loop.body for c in ast.walk(stmt) if isinstance(c, ast.Call)):
                    callee = functions.get(getattr(call.func, "id", ""))
                    if callee is None or not _takes_medium(callee) or _decorator_kw(callee).get("inline"):
                        continue
                    name = f"{path.relative_to(ROOT)}:{callee.name}"
                    checked.append(name)
                    calls = {getattr(c.func, "id", None) for c in ast.walk(callee) if isinstance(c, ast.Call)}
                    if "borrowed_medium" not in calls:
                        missing.append(name)
    assert len(checked) >= 8, checked  # the walks' task kernels are found at all
    assert not missing, f"task kernels that do not borrow their medium: {missing}"


def test_only_the_callers_arrays_are_borrowed() -> None:
    """``borrowed`` (and ``borrowed_medium`` / ``borrowed_env``) only ever take a parameter of the enclosing kernel, or
    a field of one: the caller holds those for the whole call. A borrowed local allocation would be freed by numba
    right after its last use, the borrowed view left pointing at freed memory."""
    seen, wrong = 0, []
    for path in sorted(p for tree in KERNEL_TREES for p in tree.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for fn in (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)):
            params = {a.arg for a in fn.args.args}
            for call in (c for c in ast.walk(fn) if isinstance(c, ast.Call)):
                if getattr(call.func, "id", None) not in ("borrowed", "borrowed_medium", "borrowed_env"):
                    continue
                seen += 1
                (arg,) = call.args
                root = arg.value if isinstance(arg, ast.Attribute) else arg
                if not (isinstance(root, ast.Name) and root.id in params):
                    wrong.append(f"{path.relative_to(ROOT)}:{fn.name}:{call.lineno}: {ast.unparse(arg)}")
    assert seen >= 20
    assert not wrong, wrong
