"""The compiled paths of the phi-action on the frozen L(x): the compiled Lanczos and the fused
exponential Rosenbrock-Euler step.

Where numba is installed (`agent_envs.native`, paths "lanczos" and "fused"), phi_p(c L(x)) V
for the frozen c L(x) = c (P - diag(s)) / N on numpy is computed member by member from the
kernel matrix P and its row sums s by `agent_envs.native.lanczos` (`compiled_frozen_lanczos`:
the Lanczos algorithm of `agent_envs.integrators.phi_lanczos`, the same stopping rule), and an
ERB/SERB step x + dt phi_1(dt A) (rhs + e dt A noise) + noise with the next kernel pass in one
call (`frozen_advance`; where it applies: `agent_envs.integrators.phi_functions.
frozen_advance_applies`). This module prepares their arguments: (B, N, N), (B, N), (B, N, k)
float64 C-contiguous arrays over the B batch members, read-only where the machine code was
loaded for read-only arguments.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent_envs import native
from agent_envs.dynamics.laplacian import FrozenLaplacian, readonly_view
from agent_envs.integrators.krylov_space import given_bounds
from agent_envs.native.lanczos_rule import MAX_CHECK_STEP

_NO_BOUNDS = readonly_view(np.empty(0))
_NO_EXTRA = readonly_view(np.empty((0, 0, 0)))
_FLOAT64 = np.dtype(np.float64)


def load_compiled() -> bool:
    """Whether the compiled Lanczos (`agent_envs.native.lanczos`, needs numba) serves the numpy
    frozen L(x): ``native.available("lanczos")``, loaded on the first call (the exponential
    integrators' constructors ask, so that the load falls there and not in a step). Without
    numba, or with the environment variable ``AGENT_ENVS_NUMBA=0``, False: the numpy Lanczos
    runs."""
    return native.available("lanczos")


def use_compiled(enabled: bool) -> bool:
    """Switch the compiled Lanczos and the compiled kernel pass on (when numba is installed) or
    off for this process (``native.use`` of "kernel" and "lanczos"); returns whether the
    Lanczos was in use before. For comparisons in one process (benchmarks, tests)."""
    native.use("kernel", enabled)
    return native.use("lanczos", enabled)


def load_compiled_threads(threads: int) -> bool:
    """Whether the compiled Lanczos is available and the compiled kernel pass and the fused
    exponential Rosenbrock-Euler step (`frozen_advance`) can run on `threads` threads
    (``native.load_compiled_threads``, which loads their threaded drivers)."""
    return native.available("lanczos") and native.load_compiled_threads(threads)


def compiled_frozen_lanczos(
    a: FrozenLaplacian,
    v: np.ndarray,
    order: int,
    rtol: float,
    max_dim: int,
    bounds: Any,
    add_product: tuple[np.ndarray, float] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """`agent_envs.integrators.phi_lanczos.lanczos_numpy` on c L(x) by the compiled kernel:
    (result, converged per member), or None where it does not apply (V, or W of
    `add_product`, batched beyond P). With `add_product` = (W, e) it acts on V + e (c L) W,
    the product taken in the compiled pass."""
    matrix, row_sums = a.parts()
    n, k = a.n, v.shape[-1]
    batch = tuple(matrix.shape[:-2])
    full = (*batch, n, k)
    shapes = [tuple(v.shape)]
    if add_product is not None:
        if tuple(add_product[0].shape[-2:]) != (n, k):
            return None
        shapes.append(tuple(add_product[0].shape))
    # (np.broadcast_shapes only where a shape differs: the integrators' V and W are P's)
    if any(shape != full for shape in shapes) and np.broadcast_shapes(full, *shapes) != full:
        return None
    members = math.prod(batch)
    extra, extra_scale = _NO_EXTRA, 0.0
    if add_product is not None:
        extra, extra_scale = _as_members(add_product[0], full), float(add_product[1])
    if bounds is None:
        norms = widths = lows = _NO_BOUNDS
    else:  # as `krylov_space.RowOperator.member_bounds` reads them
        norms, widths, lows = (
            readonly_view(np.ascontiguousarray(part).reshape(members))
            for part in given_bounds(bounds, batch)
        )
    peak = a.peak if a.peak is not None and a.symmetric else -1.0
    out = np.empty((members, n, k))
    converged = np.empty(members, dtype=bool)
    native.loaded("lanczos").frozen_lanczos(
        readonly_view(matrix.reshape(members, n, n)),
        readonly_view(_contiguous(row_sums).reshape(members, n)), a.scale, _as_members(v, full),
        order, rtol, max_dim, MAX_CHECK_STEP, norms, widths, lows, peak, out, converged, extra,
        extra_scale,
    )  # fmt: skip
    return out.reshape(full), converged.reshape(batch)


def _as_members(arr: np.ndarray, full: tuple[int, ...]) -> np.ndarray:
    """arr broadcast to `full` = (*batch, n, k) as a read-only float64 C-contiguous
    (members, n, k) array for the compiled calls: arr itself when it already is one (a single
    env's read-only state), a read-only view of it reshaped when it is C-contiguous float64 of
    that shape (the integrators' other arrays), a copy otherwise."""
    if type(arr) is np.ndarray and arr.shape == full and arr.dtype == _FLOAT64:
        flags = arr.flags
        if len(full) == 3 and not flags.writeable and flags.c_contiguous:
            return arr
    else:
        arr = np.broadcast_to(np.asarray(arr, dtype=np.float64), full)
    return readonly_view(_contiguous(arr).reshape(-1, *full[-2:]))


def frozen_advance(
    a: FrozenLaplacian,
    rhs: np.ndarray,
    x: np.ndarray,
    dt: float,
    noise: np.ndarray,
    extra_scale: float | None,
    p_next: np.ndarray,
    weight: float,
    alpha2: float,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """x + dt phi_1(dt A) (rhs + e dt A noise) + noise, and the kernel pass at that state, by
    the compiled `frozen_advance` (where `phi_functions.frozen_advance_applies`): (x_next,
    s_next, drift_next) with P(x_next) written into `p_next` (the workspace buffer A's P
    views), or None if some member's Lanczos did not converge within 100 dimensions (its P is
    P(x) still, the others' P(x_next): the caller discards the workspace and takes the general
    path).

    `threads` > 1 (`native.load_compiled_threads` must have answered True for it): the members in
    that many spans on numba's threads (`frozen_advance_threads`), the same bits.

    e = `extra_scale` (1 / dt for SERB's sigma A dW with sigma != 0; None: no product, ERB).
    The phi-action is `phi_functions.phi_action`'s on dt A with rtol = 1e-10 and its default
    max_krylov_dim; x_next is the integrators' x + dt phi + noise, the same operations in the
    same order, so the result equals the general path's bit for bit.
    """
    _, row_sums = a.parts()  # (parts() refuses an operator whose P was overwritten)
    *batch, n, d = full = tuple(x.shape)
    members = math.prod(batch)
    noise_members = _as_members(noise, full)
    extra = _NO_EXTRA if extra_scale is None else noise_members
    out = np.empty((members, n, d))
    x_next = np.empty((members, n, d))
    s_next = np.empty((members, n))
    drift_next = np.empty((members, n, d))
    args = (
        p_next.reshape(members, n, n),
        readonly_view(_contiguous(row_sums).reshape(members, n)),
        a.scale * float(dt), _as_members(rhs, full), 1e-10, 100, MAX_CHECK_STEP, a.peak, out,
        extra, 0.0 if extra_scale is None else float(extra_scale), _as_members(x, full),
        float(dt), noise_members, float(weight), float(alpha2), x_next, s_next, drift_next,
    )  # fmt: skip
    lanczos = native.loaded("lanczos")
    failed = native.call_on_threads(
        lanczos.frozen_advance, lanczos.frozen_advance_threads, args, members, threads
    )
    if failed:
        return None
    return x_next.reshape(x.shape), s_next, drift_next


def _contiguous(a: np.ndarray) -> np.ndarray:
    """a itself when C-contiguous (np.ascontiguousarray's call costs more than this check)."""
    return a if a.flags.c_contiguous else np.ascontiguousarray(a)
