"""Software prefetch: ask the CPU to start loading an array element's cache line before the code needs it.

A march's samples read the volume's trilinear stencils at points that lie ahead along the ray, known before the
current sample's arithmetic is done, but each read waits on memory: at 256^3 the density (64 MB) and the light volume
are far larger than the caches, and the out-of-order core cannot reach the next sample's loads past the current
sample's long, branchy body. :func:`prefetch3` is LLVM's ``llvm.prefetch`` (a read, kept in all cache levels) of
element ``[i, j, k, 0, ...]`` of an array; it changes no value, so results stay the same bit for bit. Indices must be
in bounds (no check is made: the point of it is to cost a few instructions).
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic

from photon_fields.runtime.numba_inlining import install

install()  # before any kernel that inlines ours compiles (runtime/numba_inlining.py)


@intrinsic
def prefetch3(typingctx, array, i, j, k):  # numba intrinsic: arguments are numba types
    """Prefetch the cache line of ``array[i, j, k, 0, ...]`` (an array of 3 or more dimensions) for reading."""
    if not isinstance(array, types.Array) or array.ndim < 3:
        return None
    sig = types.void(array, types.intp, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        a = context.make_array(array_type)(context, builder, args[0])
        zero = context.get_constant(types.intp, 0)
        pointer = cgutils.get_item_pointer2(context, builder, data=a.data, shape=cgutils.unpack_tuple(builder, a.shape),
                                            strides=cgutils.unpack_tuple(builder, a.strides), layout=array_type.layout,
                                            inds=[args[1], args[2], args[3]] + [zero] * (array_type.ndim - 3),
                                            wraparound=False, boundscheck=False)
        byte_pointer = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        intrinsic_type = ir.FunctionType(ir.VoidType(), [byte_pointer, i32, i32, i32])
        function = cgutils.get_or_insert_function(builder.module, intrinsic_type, "llvm.prefetch.p0")
        # (address, read = 0, locality = 3: keep in every cache level, data cache = 1)
        builder.call(function, [builder.bitcast(pointer, byte_pointer), ir.Constant(i32, 0), ir.Constant(i32, 3),
                                ir.Constant(i32, 1)])
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def prefetch_stencil(array: np.ndarray, i: int, j: int, k: int) -> None:
    """Prefetch a trilinear stencil with lower corner (i, j, k) of a C-ordered array of 3 or more dimensions: the
    four (i, j) corner pairs' lines (each pair's k + 1 neighbour, and any further axes, lie next to it)."""
    prefetch3(array, i, j, k)
    prefetch3(array, i + 1, j, k)
    prefetch3(array, i, j + 1, k)
    prefetch3(array, i + 1, j + 1, k)
