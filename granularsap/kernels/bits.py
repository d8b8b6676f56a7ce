"""Word-level bit operations used by the SuccTree.

``cttz`` (count trailing zeros) and ``ctpop`` (count set bits) lower to the
LLVM intrinsics, one instruction each (``tzcnt``/``bsf``, ``popcnt``) on
x86-64.  Under ``NUMBA_DISABLE_JIT=1`` a pure Python version is used so the
kernels can be covered as Python.
"""

from __future__ import annotations

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core.extending import intrinsic

ONE = np.uint64(1)
ALL = np.uint64(0xFFFFFFFFFFFFFFFF)

if numba.config.DISABLE_JIT:  # pragma: no cover - exercised only in the no-JIT job

    def cttz(x):
        x = int(x)
        return np.uint64((x & -x).bit_length() - 1)

    def ctpop(x):
        return np.uint64(bin(int(x)).count("1"))

else:

    @intrinsic
    def cttz(typingctx, x):
        """Index of the lowest set bit of a non-zero uint64."""
        if x != types.uint64:
            return None
        sig = types.uint64(types.uint64)

        def codegen(context, builder, signature, args):
            return builder.cttz(args[0], ir.Constant(ir.IntType(1), 1))

        return sig, codegen

    @intrinsic
    def ctpop(typingctx, x):
        """Number of set bits of a uint64 (``popcnt``)."""
        if x != types.uint64:
            return None
        sig = types.uint64(types.uint64)

        def codegen(context, builder, signature, args):
            return builder.ctpop(args[0])

        return sig, codegen
