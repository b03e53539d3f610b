"""Standard normals from many numpy generators in one compiled call (numba, optional).

This module imports numba (and llvmlite, which numba brings); the package imports it only
through `agent_envs.native.loader` (path "noise"), so the package works without numba (each
generator's own `standard_normal(out=...)` then runs, one Python call per generator).

The native vector env draws each env's Brownian increments from that env's own generator, as
its single twin does, so the two give the same bits. With numpy that is one call per env:
about 0.8 us of call overhead each, 2.1 us per env for 100 normals (N = 100, d = 1, one path),
more than the draws themselves. Here the whole batch is one call: each generator is reached
through the C interface numpy gives every bit generator (`BitGenerator.ctypes`: the address
of its state and its `next_uint64` and `next_double` functions), and the normals come from
numpy's own algorithm, the 256-step ziggurat of `random_standard_normal` (numpy's
`numpy/random/src/distributions/distributions.c`), on the same words of the bit generator in
the same order, with numpy's tables (as numba's port of that function has them,
`numba.np.random._constants`). So the values are numpy's bit for bit, and the generators'
states advance exactly as numpy's calls would advance them: a later numpy draw from the same
generator continues the same stream. The loader checks this against numpy when it loads the
module (`agent_envs.draws._draws_equal_numpys`, the owner's check; a mismatch, say from
another numba's tables, switches the compiled draws off with a warning), and
tests/test_simulator.py checks it on a million draws.

numpy's Generator methods hold the bit generator's lock while they draw; these calls do not,
so the generators must not be used from another thread during a call (`GeneratorHandles`).
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic
from numba.np.random._constants import (
    fi_double,
    ki_double,
    wi_double,
    ziggurat_nor_inv_r,
    ziggurat_nor_r,
)

_KI = np.asarray(ki_double, dtype=np.uint64)
_WI = np.asarray(wi_double, dtype=np.float64)
_FI = np.asarray(fi_double, dtype=np.float64)
_R = float(ziggurat_nor_r)
_INV_R = float(ziggurat_nor_inv_r)


def _call_on_state(result: ir.Type):
    """codegen: call the C function at address args[0] on the state pointer args[1]."""

    def codegen(context, builder, signature, args):
        function, state = args
        void_ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(result, [void_ptr])
        callee = builder.inttoptr(function, fnty.as_pointer())
        return builder.call(callee, [builder.inttoptr(state, void_ptr)])

    return codegen


@intrinsic
def _next_uint64(typingctx, function, state):
    """uint64_t next_uint64(void *state), the bit generator's C function at `function`."""
    return types.uint64(types.uintp, types.uintp), _call_on_state(ir.IntType(64))


@intrinsic
def _next_double(typingctx, function, state):
    """double next_double(void *state), the bit generator's C function at `function`."""
    return types.float64(types.uintp, types.uintp), _call_on_state(ir.DoubleType())


@njit(cache=True, error_model="numpy")
def standard_normal(state: int, next_u64: int, next_dbl: int) -> float:
    """One standard normal from the bit generator at `state`: numpy's `random_standard_normal`
    (the ziggurat: one 64-bit word per draw but for the 1-2 % that fall outside a rectangle)."""
    while True:
        r = _next_uint64(next_u64, state)
        idx = r & 0xFF
        r >>= 8
        sign = r & 0x1
        rabs = (r >> 1) & 0x000FFFFFFFFFFFFF
        x = rabs * _WI[idx]
        if sign & 0x1:
            x = -x
        if rabs < _KI[idx]:
            return x
        if idx == 0:  # the tail beyond r
            while True:
                xx = -_INV_R * math.log1p(-_next_double(next_dbl, state))
                yy = -math.log1p(-_next_double(next_dbl, state))
                if yy + yy > xx * xx:
                    if (rabs >> 8) & 0x1:
                        return -(_R + xx)
                    return _R + xx
        elif (_FI[idx - 1] - _FI[idx]) * _next_double(next_dbl, state) + _FI[idx] < math.exp(
            -0.5 * x * x
        ):
            return x


@njit(cache=True, error_model="numpy")
def fill_standard_normal(
    states: np.ndarray,
    next_u64: np.ndarray,
    next_dbl: np.ndarray,
    sources: np.ndarray,
    rows: np.ndarray,
    out: np.ndarray,
    scale: float,
) -> None:
    """out[rows[k], :] = scale * (standard normals of generator sources[k]), in order, for
    out (B, M) C-contiguous; the other rows are left as they are. states, next_u64, next_dbl
    (G,) the generators' state addresses and function addresses; sources, rows (K,) int64.
    Each value is numpy's normal times `scale`: one IEEE product, as numpy's `out *= scale`."""
    width = out.shape[1]
    for k in range(rows.shape[0]):
        g = sources[k]
        state, u64, dbl = states[g], next_u64[g], next_dbl[g]
        row = out[rows[k]]
        for i in range(width):
            row[i] = standard_normal(state, u64, dbl) * scale
