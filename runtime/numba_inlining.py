"""A faster copy of inlined IR for numba's ``inline="always"``: one copy of a function's scope per copy, not per block.

Our walks inline deep chains of kernels at numba's IR level (``inline="always"``; runtime/transport/tracking.py says
why). numba's ``InlineWorker.inline_ir`` copies the callee's IR before splicing it in, and copies it block by block,
each block with ``copy.deepcopy`` and a memo of its own (numba/core/inline_closurecall.py, ``copy_ir``). Every
variable refers to the function's one ``Scope``, which holds all of its variables, so each block's copy copies the
whole scope again: blocks x variables. For NEE's item loop (the ratio-tracking walk inlined three levels deep) that
was most of its compile time (bench/README.md, "Cold compiles"; numba issues #8989, #9204 describe the same copies).

:func:`install` makes the blocks of one copied IR share one copy of its scope: the copies are equal to numba's
(numba itself keeps one scope per function: ``inline_ir`` then asserts that the copied blocks have one scope, which
with numba's copies holds only because equal copies compare equal), the same IR reaches the same lowering, and the
kernels compute the same numbers (renders byte for byte the same; the whole suite runs with it). It is a patch of
numba's internals, so it applies only where ``copy_ir`` is the code it was written against (the source of
``inline_ir`` is checked) and does nothing otherwise, or when the environment sets ``PFN_NUMBA_INLINE_COPY=0``.
Every module of ours that defines an ``inline="always"`` kernel installs it at import (it calls :func:`install` or
imports a module that does), so it is in place before any kernel that inlines one compiles
(tests/runtime/test_numba_inlining.py checks both). Without it, numba compiles the same kernels, more slowly.
"""

from __future__ import annotations

import copy
import inspect
import os
import threading
from typing import Any

#: The statement of numba's ``copy_ir`` this patch replaces the effect of; without it in ``inline_ir``'s source
#: (another numba), :func:`install` leaves numba alone.
_EXPECTED = "new_block = copy.deepcopy(the_ir.blocks[block_label])"
_state = threading.local()
_installed: bool | None = None


class _SharedScopeCopy:
    """Stands for the ``copy`` module inside numba's inline_closurecall (which uses it for ``copy_ir`` alone): while
    ``inline_ir`` runs, the blocks of one IR are deep-copied with one copy of their scope."""

    @staticmethod
    def deepcopy(x: Any, memo: dict[int, Any] | None = None) -> Any:
        scopes = getattr(_state, "scopes", None)
        scope = getattr(x, "scope", None)
        if memo is None and scopes is not None and scope is not None:
            key = id(scope)
            if key not in scopes:  # the source scope is kept alive with its copy, so its id is not reused
                scopes[key] = (scope, copy.deepcopy(scope))
            memo = {key: scopes[key][1]}
        return copy.deepcopy(x, memo)

    def __getattr__(self, name: str) -> Any:
        return getattr(copy, name)


def install() -> bool:
    """Patch numba's inliner once per process (module docstring); whether the patch is in place."""
    global _installed
    if _installed is not None:
        return _installed
    _installed = False
    if os.environ.get("PFN_NUMBA_INLINE_COPY", "1") == "0":
        return False
    from numba.core import inline_closurecall

    worker = inline_closurecall.InlineWorker
    try:
        source = inspect.getsource(worker.inline_ir)
    except (OSError, TypeError):
        return False
    if _EXPECTED not in source or getattr(inline_closurecall, "copy", None) is not copy:
        return False
    inline_ir = worker.inline_ir

    def inline_ir_sharing_scopes(self: Any, *args: Any, **kwargs: Any) -> Any:
        outer = getattr(_state, "scopes", None)
        _state.scopes = {}
        try:
            return inline_ir(self, *args, **kwargs)
        finally:
            _state.scopes = outer

    inline_ir_sharing_scopes.__wrapped__ = inline_ir  # type: ignore[attr-defined]
    worker.inline_ir = inline_ir_sharing_scopes
    inline_closurecall.copy = _SharedScopeCopy()
    _installed = True
    return True
