"""Borrowed arrays: the same array without numba's reference counting, for the inner loops of a task.

numba counts references to an array's memory (its ``meminfo``) with atomic increments and decrements. Its pruning
pass removes the pairs it can prove redundant, but not those around an inlined kernel that loops or returns early:
there every call site in a walk (``leap_if_empty``, the marched estimator's ``_score``) increments and decrements
each array it passes, several times per macrocell step. In a marched frame that was 7-10 % of the walk's and of
the picks' shadow rays' time (``bench/profile_frame.py``: ``NRT_incref`` / ``NRT_decref``).

:func:`borrowed` returns the array with no meminfo: numba's increments and decrements of it find a null pointer
and return at once, and LLVM no longer has an atomic operation to keep in the loop. It is safe where the borrowed
array lives no longer than its owner's reference: a serial task kernel that borrows its *parameters'* arrays at its
start, while its caller (the parallel loop, or Python) holds them. Never borrow an array the kernel allocates itself:
numba frees it right after its last use, which the borrowing is (scratch a task needs is allocated by its caller and
passed in; ``tests/runtime/test_borrowed.py`` checks that only parameters are borrowed). A borrowed array must not be
returned or stored where it outlives the call.
"""

from __future__ import annotations

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic


@intrinsic
def borrowed(typingctx, array):  # numba intrinsic: arguments are numba types
    """``array`` without its meminfo and parent (module docstring): the same data, shape and strides."""
    if not isinstance(array, types.Array):
        return None

    def codegen(context, builder, signature, args):
        source = context.make_array(signature.args[0])(context, builder, args[0])
        out = context.make_array(signature.return_type)(context, builder)
        out.meminfo = cgutils.get_null_value(out.meminfo.type)
        out.parent = cgutils.get_null_value(out.parent.type)
        out.nitems = source.nitems
        out.itemsize = source.itemsize
        out.data = source.data
        out.shape = source.shape
        out.strides = source.strides
        return out._getvalue()

    return array(array), codegen
