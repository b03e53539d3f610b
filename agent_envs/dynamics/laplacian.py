"""The frozen linearization L(x) as a dense-backed operator built in a reusable workspace.

For the Cucker-Smale kernel on numpy states, `SwarmModel` evaluates the drift and L(x) of
`eq:dyn_matrix` from one kernel matrix P (..., N, N) and one product

    P [x | 1] = [P x | s],    s = P 1 (the row sums),    F(x) = L(x) x = (P x - s * x) / N,

without forming L = (P - diag(s)) / N, its scaled copy tau L, or any other (..., N, N)
temporary: P lives in a `KernelWorkspace` owned by the model, allocated once per batch shape
and overwritten in place by the next evaluation (so a fresh process runs at the warm speed:
glibc maps every allocation above its mmap threshold afresh and page-faults it on first touch).

`FrozenLaplacian` is what the exponential integrators receive in place of the matrix c L(x):
``op @ V = c (P V - s * V) / N`` for V (..., N, k), ``c * op`` (sharing P), `dense()` (a fresh
c L array, for the dense phi strategies), and the two bounds the Krylov phi-action needs per
batch member, both from quantities the drift already has (s, and p_max = w / alpha^2 = P_kk):

- ``norm_inf = c ||L||_inf = 2 c max_k (s_k - p_max) / N`` (exact: P > 0 off the diagonal, and
  L_kk = (P_kk - s_k)/N); it scales the Lanczos breakdown test.
- ``cluster_width = 2 c max_k (p_max - s_k / N)`` for the symmetric kernel: L 1 = 0, and on
  1^perp (L is symmetric) L = -p_max I + (graph Laplacian of E)/N with E = p_max 1 1^T - P >= 0
  entrywise, whose eigenvalues lie in [0, 2 max_k (E 1)_k]; so spec(c L) is {0} together with an
  interval of that width above -c p_max. Near consensus the width is tiny and Lanczos converges
  in a few steps; `phi_functions` deflates the constant vector (L 1 = 0) and uses the width to
  decide from which Krylov dimension its a posteriori error estimate may be trusted.

With numba the compiled pass (`agent_envs.native.kernel`, the compiled path "kernel"; this
module's numpy passes are its reference) writes only P's lower triangle (and its diagonal),
which is all that the compiled Lanczos and the drift read; the operator's `UpperTriangle`
fills the rest the first time a consumer of the whole P asks (`matrix`, `dense()`, `@`), so an
Euler-Maruyama or compiled SERB step never pays for it.

A `FrozenLaplacian` refers to the workspace it was built in: the model's next evaluation
overwrites P, and using an operator built before that raises `RuntimeError` (never a silent stale
product). The public `SwarmModel.frozen_linearization` still returns a fresh array.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent_envs import arrays, native

# (kept for callers of the names this module had before the native layer: the loader, the
# switch and the thread dispatch of every compiled path live in `agent_envs.native`)
from agent_envs.native import call_on_threads as call_on_threads
from agent_envs.native import check_compiled_threads as check_compiled_threads
from agent_envs.native import compiled_threads as compiled_threads
from agent_envs.native import import_checked as import_checked
from agent_envs.native import import_compiled as import_compiled
from agent_envs.native import load_compiled_threads as load_compiled_threads
from agent_envs.native import max_compiled_threads as max_compiled_threads

#: (kept as well) the environment variable that switches every compiled path off
COMPILED_ENV_VAR = native.ENV_VAR
#: batch shapes a `KernelWorkspace` keeps buffers for (the oldest is dropped beyond this)
_MAX_SHAPES = 2


def readonly_view(a: np.ndarray) -> np.ndarray:
    """A read-only view of `a` (the workspace hands out its P so; the compiled calls take
    read-only inputs only: numba keeps one machine code per argument type, and read-only is part
    of the type, so a second, writable type would be loaded at its first call, in a step)."""
    view = a.view()
    view.flags.writeable = False
    return view


def load_compiled_kernel() -> bool:
    """Whether the compiled kernel pass (`agent_envs.native.kernel`, needs numba) builds P, its
    row sums and the drift for the symmetric Cucker-Smale kernel: ``native.available("kernel")``
    (loaded on the first call: `SwarmModel` asks when it is made, not in a step). Without
    numba, or with ``AGENT_ENVS_NUMBA=0``, False: `fill_cucker_smale` and one product
    P [x | 1] run."""
    return native.available("kernel")


def use_compiled_kernel(enabled: bool) -> bool:
    """``native.use("kernel", enabled)``: switch the compiled kernel pass on (when numba is
    installed) or off for this process; returns whether it was in use before."""
    return native.use("kernel", enabled)


def compiled_cucker_smale_drift(
    x: np.ndarray, weight: float, alpha2: float, p: np.ndarray, threads: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """(s, L(x) x) with the lower triangle of P (and its diagonal) written into `p` (..., N, N)
    by the compiled pass, for x (..., N, d) and the symmetric kernel with scalar weight w
    (``native.available("kernel")`` must have answered True); `UpperTriangle` fills the rest
    when a consumer of the whole P asks for it. `threads` > 1
    (``native.load_compiled_threads`` must have answered True): the members on that many
    threads, the same bits."""
    *batch, n, d = x.shape
    members = math.prod(batch)
    flat = readonly_view(np.ascontiguousarray(x, dtype=np.float64).reshape(members, n, d))
    row_sums = np.empty((members, n))
    drift = np.empty((members, n, d))
    kernel = native.loaded("kernel")
    native.call_on_threads(
        kernel.cucker_smale_drift,
        kernel.cucker_smale_drift_threads,
        (flat, float(weight), float(alpha2), p.reshape(members, n, n), row_sums, drift),
        members,
        threads,
    )
    return row_sums.reshape(*batch, n), drift.reshape(*batch, n, d)


class UpperTriangle:
    """The upper triangle of a workspace's P that the compiled kernel pass left unwritten
    (it writes the lower one, which is all that the compiled Lanczos and the drift read).

    The operators of one evaluation share one instance; `complete` mirrors the lower triangle
    into the upper one once (compiled, or numpy without numba), the first time a consumer of
    the whole P (a numpy product, `FrozenLaplacian.dense`, `FrozenLaplacian.matrix`) asks.
    """

    def __init__(self, buffer: np.ndarray) -> None:
        self._buffer = buffer  # the workspace's writable P, (..., N, N)
        self.done = False

    def complete(self) -> None:
        if self.done:
            return
        p = self._buffer
        n = p.shape[-1]
        if native.available("kernel"):
            native.loaded("kernel").mirror_lower(p.reshape(-1, n, n))
        else:
            upper = np.triu_indices(n, 1)
            p[..., upper[0], upper[1]] = p[..., upper[1], upper[0]]
        self.done = True


class KernelWorkspace:
    """Buffers of the dense kernel evaluation, one set per state shape (..., N, d).

    The kernel matrix P (..., N, N), `augmented` ([x | 1], (..., N, d + 1)), `product`
    (P [x | 1], (..., N, d + 1)) and, for d > 1, a scratch (..., N, N) for the coordinate
    differences. `generation` counts the evaluations; an operator built at one generation is
    valid until the next.
    """

    def __init__(self) -> None:
        self.generation = 0
        self._buffers: dict[tuple[int, ...], tuple[Any, ...]] = {}

    def buffers(self, shape: tuple[int, ...]) -> tuple[Any, ...]:
        """(P, [x | 1], P [x | 1], scratch or None) for states of `shape` (..., N, d), made
        once."""
        found = self._buffers.get(shape)
        if found is None:
            *batch, n, d = shape
            augmented = np.empty((*batch, n, d + 1))
            augmented[..., d] = 1.0
            scratch = np.empty((*batch, n, n)) if d > 1 else None
            # P aligned to a cache line: the compiled kernel pass and Lanczos read its rows
            # with vector loads (`arrays.aligned_empty`)
            p = arrays.aligned_empty((*batch, n, n))
            found = (p, augmented, np.empty((*batch, n, d + 1)), scratch)
            if len(self._buffers) >= _MAX_SHAPES:
                self._buffers.pop(next(iter(self._buffers)))
            self._buffers[shape] = found
        return found


def fill_cucker_smale(
    x: np.ndarray,
    alpha: float,
    weights: float | np.ndarray,
    out: np.ndarray,
    scratch: np.ndarray | None = None,
) -> np.ndarray:
    """P[..., k, l] = w_l / (alpha^2 + |x_k - x_l|^2) written into `out` (..., N, N).

    x (..., N, d) float64; `weights` a float or an (N,) array (index l). Four passes over `out`
    for d = 1 (difference, square, + alpha^2, w / .); for d > 1 the squared distances are summed
    coordinate by coordinate into `out` through `scratch` (shaped like `out`; a fresh one if
    None), never an (..., N, N, d) temporary.
    """
    d = x.shape[-1]
    np.subtract(x[..., None, :, 0], x[..., :, None, 0], out=out)
    np.multiply(out, out, out=out)
    if d > 1:
        diff = np.empty_like(out) if scratch is None else scratch
        for i in range(1, d):
            np.subtract(x[..., None, :, i], x[..., :, None, i], out=diff)
            np.multiply(diff, diff, out=diff)
            out += diff
    out += alpha * alpha
    return np.divide(weights, out, out=out)


def krylov_bounds(
    row_sums: np.ndarray,
    diagonal: float | np.ndarray,
    n: int,
    peak: float | None,
    symmetric: bool,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The Krylov bounds of L = (P - diag(s)) / N for a kernel with P > 0, per member (...,).

    Args:
        row_sums: s = P 1, (..., N) (numpy).
        diagonal: P_kk, a float or (N,).
        n: N.
        peak: p_max with P_kl <= p_max = P_kk for all k, l (the symmetric Cucker-Smale
            kernel), else None.
        symmetric: whether P is symmetric.

    Returns:
        ``(||L||_inf, width)``: ``||L||_inf = 2 max_k (s_k - P_kk) / N`` (exact for P > 0
        off the diagonal), and the width ``2 max_k (p_max - s_k / N)`` of an interval holding
        spec(L) except its eigenvalue 0 (module docstring), or None without a peak.
    """
    norms = (2.0 / n) * np.max(np.abs(row_sums - diagonal), axis=-1)
    if peak is None or not symmetric:
        return norms, None
    widths = 2.0 * np.maximum(np.max(peak - row_sums / n, axis=-1), 0.0)
    return norms, widths


class FrozenLaplacian:
    """c L(x) = c (P - diag(s)) / N as an operator over a workspace's P (see module doc).

    Attributes:
        matrix: P (..., N, N) (read-only view of the workspace buffer; reading it first fills
            an upper triangle the compiled kernel pass left unwritten, `UpperTriangle`).
        row_sums: s = P 1, (..., N).
        scale: the factor c.
        symmetric: whether P is symmetric (then so is L).
        peak: p_max = max p (the kernel at distance 0) when every P_kl <= p_max = P_kk, which
            enables `cluster_width`; None otherwise.
    """

    def __init__(
        self,
        matrix: np.ndarray,
        row_sums: np.ndarray,
        *,
        scale: float = 1.0,
        symmetric: bool,
        peak: float | None,
        workspace: KernelWorkspace,
        generation: int,
        upper: UpperTriangle | None = None,
    ) -> None:
        self._matrix = matrix
        self._upper = upper
        self.row_sums = row_sums
        self.scale = float(scale)
        self.symmetric = bool(symmetric)
        self.peak = peak
        self._workspace = workspace
        self._generation = generation
        self.n = matrix.shape[-1]
        self._factor = self.scale / self.n
        self._weights = row_sums[..., :, None]  # (..., N, 1): s * V for V (..., N, k)
        self._row_weights = row_sums[..., None, :]  # (..., 1, N): s * W for rows W (..., k, N)

    def __getstate__(self) -> dict[str, Any]:
        """For copy and pickle: the upper triangle filled first (a copy of the read-only view
        of P and a copy of the workspace's buffer are two arrays, and only the buffer would be
        filled later): reading `matrix` fills it."""
        self.matrix  # noqa: B018  (the property's side effect is the point)
        return self.__dict__.copy()

    @property
    def matrix(self) -> np.ndarray:
        """P (..., N, N), read-only; whole (`UpperTriangle.complete` first where the compiled
        kernel pass wrote only its lower triangle and P is still this operator's)."""
        if self._upper is not None and not self._upper.done and self.current:
            self._upper.complete()
        return self._matrix

    @property
    def current(self) -> bool:
        """Whether the workspace still holds this operator's P."""
        return self._workspace.generation == self._generation

    def _check(self) -> None:
        if not self.current:
            raise RuntimeError(
                "this linearization's kernel matrix was overwritten by a later evaluation of "
                "the model (the dense workspace holds one P per shape); evaluate it again"
            )

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self._matrix.shape)

    @property
    def dtype(self) -> np.dtype:
        return self._matrix.dtype

    def parts(self) -> tuple[np.ndarray, np.ndarray]:
        """(P, s): the kernel matrix (read-only) and its row sums, for a compiled phi-action,
        which reads only P's lower triangle and diagonal (the upper triangle may be unwritten:
        `matrix` is the whole P); `RuntimeError` once P was overwritten."""
        self._check()
        return self._matrix, self.row_sums

    def matvec(self, v: Any) -> np.ndarray:
        """c L V for V (..., N, k)."""
        self._check()
        out = self.matrix @ v
        out -= self._weights * v
        out *= self._factor
        return out

    def __matmul__(self, v: Any) -> np.ndarray:
        return self.matvec(v)

    def apply_rows(self, rows: np.ndarray) -> np.ndarray:
        """(c L W^T)^T for rows W (..., k, N): what the Krylov recurrences multiply with."""
        self._check()
        if self.symmetric:
            out = rows @ self.matrix
        else:
            out = rows @ np.swapaxes(self.matrix, -1, -2)
        out -= self._row_weights * rows
        out *= self._factor
        return out

    def scaled(self, c: float) -> FrozenLaplacian:
        """c' c L sharing P and s."""
        return FrozenLaplacian(
            self._matrix,
            self.row_sums,
            scale=self.scale * float(c),
            symmetric=self.symmetric,
            peak=self.peak,
            workspace=self._workspace,
            generation=self._generation,
            upper=self._upper,
        )

    def __mul__(self, c: float) -> FrozenLaplacian:
        if not isinstance(c, (int, float, np.floating, np.integer)):
            return NotImplemented
        return self.scaled(float(c))

    __rmul__ = __mul__

    def dense(self) -> np.ndarray:
        """c L as a fresh (..., N, N) array."""
        self._check()
        out = np.array(self.matrix)
        idx = np.arange(self.n)
        out[..., idx, idx] -= self.row_sums
        out *= self._factor
        return out

    @property
    def max_abs(self) -> np.ndarray:
        """max_kl |c L_kl| per member, (..., 1): |c| max_k (s_k - P_kk) / N (P > 0, so the
        diagonal entry of each row is its largest), half of ||c L||_inf."""
        return 0.5 * self.krylov_bounds()[0][..., None]

    def krylov_bounds(self) -> tuple[np.ndarray, np.ndarray | None, float | None]:
        """(||c L||_inf, width of spec(c L) without 0 or None) per batch member: `krylov_bounds`
        of the row sums and the diagonal of P, times |c|; and the bottom -c p_max of the
        interval of that width holding spec(c L) on 1^perp, for c > 0 (None otherwise): L is
        -p_max plus a graph Laplacian of p_max - P there, whose spectrum lies in [0, width / c]
        (`lanczos_stopping.spectrum_interval`)."""
        idx = np.arange(self.n)
        norms, widths = krylov_bounds(
            self.row_sums, self._matrix[..., idx, idx], self.n, self.peak, self.symmetric
        )
        c = abs(self.scale)
        low = None
        if widths is not None and self.scale > 0:
            low = -self.scale * self.peak
        return c * norms, None if widths is None else c * widths, low

    def __repr__(self) -> str:
        return f"FrozenLaplacian(shape={self.shape}, scale={self.scale})"
