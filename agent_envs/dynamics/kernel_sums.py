"""Kernel sums sum_l p(x_k, x_l) v_l without the N x N matrix.

Two evaluators of the same sums, for one configuration x (N, d) and blocks of vectors V (N, k):

- `ChunkedKernelSum`: the exact pairwise reduction, a block of `block` rows of P at a time,
  for every dimension d and every kernel object (`kernel.value` on a slice of the pairs).
  O(N^2) time, O(N * block) memory. The reference for the grid sum, and the path for d >= 3,
  for other kernels and for d = 2 below a few thousand agents.
- `GridKernelSum` (d <= 2, kernels of the form p(x_k, x_l) = w_l g(x_k - x_l)): the
  kernel-independent interpolation on a uniform grid. In d = 1, with the local p-point Lagrange
  interpolation weights l_i(x) on the grid g_i = g_0 + i h,

      g(x_k - x_l) ~ sum_i sum_j l_i(x_k) l_j(x_l) g((i - j) h),

  so  sum_l w_l g(x_k - x_l) v_l ~ (W C W^T (w v))_k  with W[k, i] = l_i(x_k) (a sparse N x G
  matrix, p nonzeros a row) and C[i, j] = g((i - j) h) a Toeplitz matrix applied by FFT.
  For the Cucker-Smale profiles g(r) = 1/(alpha^2 + r^2) and r/(alpha^2 + r^2), analytic in
  the strip |Im r| < alpha, the error of the p-point interpolation with h = alpha / c falls
  geometrically in p once c is of the order of p (see `grid_resolution`); `grid_resolution(tol)`
  gives the (c, p) measured to reach `tol` as relative error of the sums
  (tests/test_large_swarms.py checks the default against the exact sums).
  O(N p + G log G) per product with G = (max x - min x) / h + p grid points: linear in N
  whatever the clustering of the agents (no near field), so the fast path for large N.
  The grid grows with the spread of the swarm in units of alpha; `GridKernelSum.fits`
  says when it stays below `MAX_GRID_POINTS` (otherwise use the chunked sum). In d = 2 the
  interpolation is the tensor product (p^2 weights per agent) and the Toeplitz product a 2-D
  FFT of the G_1 x G_2 grid, the same accuracy for the same (c, p).

Why not a non-uniform FFT (e.g. finufft) on the Lorentzian's Fourier transform
(pi/alpha) e^{-alpha |omega|}: the kernel decays only like 1/r^2, so a periodized Fourier
representation needs a near-field/far-field splitting to reach 1e-10, and its transforms alone
cost more at N = 10^6 than the whole grid product here (benchmarks/bench_large_swarms.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import scipy.fft
import scipy.sparse

from agent_envs.dynamics.kernels import CuckerSmaleKernel, InteractionKernel

# Largest uniform grid (points) of `GridKernelSum`; beyond it the swarm is too spread out in
# units of alpha for the grid and the chunked sum is used.
MAX_GRID_POINTS = 2**24
DEFAULT_TOLERANCE = 1e-12


def grid_resolution(tol: float) -> tuple[float, int]:
    """(c, p): grid step h = alpha / c and p interpolation points reaching `tol`.

    The equispaced p-point interpolation converges geometrically only when the stencil is
    narrow against the distance alpha of the profiles' poles (c of the order of p or more;
    with c = 4 the error stalls near 1e-5 whatever p). The pairs in `_RESOLUTIONS` were
    measured on N = 2000 uniform points of [-1, 1], alpha = 0.1 (relative 2-norm error of the
    sums against the exact ones, random v, both profiles).
    """
    if not 0 < tol < 1:
        raise ValueError(f"tol must be in (0, 1), got {tol}")
    for bound, c, p in _RESOLUTIONS:
        if tol >= bound:
            return c, p
    return _RESOLUTIONS[-1][1], _RESOLUTIONS[-1][2]


# (tolerance, c, p): the cheapest measured (c, p) whose error is below the tolerance, from the
# loosest tolerance to the tightest (tests/test_large_swarms.py checks the default).
_RESOLUTIONS: list[tuple[float, float, int]] = [
    (1e-6, 16.0, 6),
    (1e-8, 16.0, 8),
    (1e-10, 32.0, 8),
    (1e-12, 32.0, 10),
    (1e-14, 48.0, 10),
]


def lagrange_weights(u: np.ndarray, p: int) -> np.ndarray:
    """l_j(u) = prod_{m != j} (u - m)/(j - m), j = 0..p-1, for u (N,); returns (N, p).

    Products of the differences to the left and to the right of j (no division by u - j, so
    exact at the nodes).
    """
    diff = [u - m for m in range(p)]  # p arrays (N,): loops over p, vector ops over N
    left = [np.ones_like(u)]
    for m in range(p - 1):
        left.append(left[-1] * diff[m])
    out = np.empty((p, u.size))  # contiguous rows, transposed once at the end (measured
    right = np.ones_like(u)  # ~30 % faster than writing the strided columns of (N, p))
    for j in range(p - 1, -1, -1):
        np.multiply(left[j], right, out=out[j])
        out[j] /= math.prod(j - m for m in range(p) if m != j)
        right = right * diff[j]
    return out.T.copy()


class GridKernelSum:
    """sum_l w_l g_a(x_k - x_l) v_l on a uniform grid, several profiles g_a (module docstring).

    In d dimensions the interpolation is the tensor product of the 1-D one (p^d grid points
    per agent) and the Toeplitz product a d-dimensional FFT; the grid has
    prod_c (32 span_c / alpha + p) points, so it is meant for d <= 2 (`fits`).

    Args:
        points: the agents' positions, (N,) (then the profiles get r of shape (...)) or (N, d)
            (then the profiles get r of shape (..., d)).
        profiles: functions g(r) of the offsets r = x_k - x_l.
        weights: w_l, a float or an (N,) array.
        length_scale: alpha (the half-width of the strip where the profiles are analytic).
        tol: the relative accuracy (see `grid_resolution`).
    """

    def __init__(
        self,
        points: np.ndarray,
        profiles: Sequence[Callable[[np.ndarray], np.ndarray]],
        weights: float | np.ndarray,
        length_scale: float,
        tol: float = DEFAULT_TOLERANCE,
    ) -> None:
        x = np.asarray(points, dtype=float)
        if x.ndim not in (1, 2):
            raise ValueError(f"points must have shape (N,) or (N, d), got {x.shape}")
        scalar_offsets = x.ndim == 1
        x = x[:, None] if scalar_offsets else x
        n, dim = x.shape
        c, p = grid_resolution(tol)
        h = length_scale / c
        shape = self.grid_shape(x, length_scale, tol)
        n_grid = math.prod(shape)
        if n_grid > MAX_GRID_POINTS:
            raise ValueError(
                f"the swarm spans {np.ptp(x, axis=0)} = {n_grid} grid points of "
                f"alpha/{c:g} (more than {MAX_GRID_POINTS}); use the chunked kernel sum"
            )
        # per axis: the first stencil index and the p Lagrange weights of every agent
        data = np.ones((n, 1))
        cols = np.zeros((n, 1), dtype=np.int64)
        for axis in range(dim):
            t = (x[:, axis] - (float(x[:, axis].min()) - (p // 2) * h)) / h
            start = np.floor(t).astype(np.int64) - (p // 2 - 1)
            idx = start[:, None] + np.arange(p)[None, :]  # (N, p)
            w = lagrange_weights(t - start, p)
            if dim == 1:
                data, cols = w, idx
            else:  # row-major flat index over the grid, p^(axis+1) stencil points per agent
                data = (data[:, :, None] * w[:, None, :]).reshape(n, -1)
                cols = (cols[:, :, None] * shape[axis] + idx[:, None, :]).reshape(n, -1)
        stencil = data.shape[1]
        self._interp = scipy.sparse.csr_matrix(
            (data.ravel(), cols.ravel(), np.arange(0, n * stencil + 1, stencil)),
            shape=(n, n_grid),
        )
        self._spread = self._interp.T  # CSC: its product with a dense block needs no copy
        self._weights = weights if np.ndim(weights) == 0 else np.asarray(weights)[:, None]
        sizes = tuple(scipy.fft.next_fast_len(2 * g - 1, real=True) for g in shape)
        # circular layout of c_m = g(m h), m = i - j per axis: index m mod size (the entries
        # between G and size - G + 1 are never read by the cropped product: left at 0)
        axes_offsets = []
        for g, size in zip(shape, sizes, strict=True):
            m = np.arange(size)
            m = np.where(m < g, m, m - size)
            axes_offsets.append(np.where(np.abs(m) < g, m, 0) * h)
        mesh = np.stack(np.meshgrid(*axes_offsets, indexing="ij"), axis=-1)  # (*sizes, d)
        valid = np.ones(sizes, dtype=bool)
        for axis, (g, size) in enumerate(zip(shape, sizes, strict=True)):
            m = np.arange(size)
            ok = (m < g) | (m > size - g)
            valid &= ok.reshape([-1 if a == axis else 1 for a in range(dim)])
        r = mesh[..., 0] if scalar_offsets else mesh
        self._spectra = [scipy.fft.rfftn(np.where(valid, g(r), 0.0), s=sizes) for g in profiles]
        self._sizes = sizes
        self.shape = shape
        self.n_grid = n_grid

    @staticmethod
    def grid_shape(
        points: np.ndarray, length_scale: float, tol: float = DEFAULT_TOLERANCE
    ) -> tuple[int, ...]:
        """The grid points per axis the grid for these points (N,) or (N, d) needs."""
        c, p = grid_resolution(tol)
        x = np.asarray(points, dtype=float)
        x = x[:, None] if x.ndim == 1 else x
        spans = np.max(x, axis=0) - np.min(x, axis=0)
        return tuple(math.ceil(float(span) * c / length_scale) + p + 2 for span in spans)

    @classmethod
    def grid_points(
        cls, points: np.ndarray, length_scale: float, tol: float = DEFAULT_TOLERANCE
    ) -> int:
        """The number of grid points G the grid for these points needs."""
        return math.prod(cls.grid_shape(points, length_scale, tol))

    @classmethod
    def fits(cls, points: np.ndarray, length_scale: float, tol: float = DEFAULT_TOLERANCE):
        """Whether the grid for these points stays within `MAX_GRID_POINTS`."""
        return cls.grid_points(points, length_scale, tol) <= MAX_GRID_POINTS

    def __call__(self, v: np.ndarray, select: Sequence[int] | None = None) -> list[np.ndarray]:
        """[sum_l w_l g_a(x_k - x_l) v_l for each profile g_a], each (N, k), for v (N, k).

        `select`: the indices of the profiles wanted (default all).
        """
        k = v.shape[1]
        q = (self._spread @ (self._weights * v)).reshape(*self.shape, k)  # (*grid, k)
        axes = tuple(range(len(self.shape)))
        q_hat = scipy.fft.rfftn(q, s=self._sizes, axes=axes)
        crop = tuple(slice(0, g) for g in self.shape)
        out = []
        spectra = self._spectra if select is None else [self._spectra[i] for i in select]
        for spectrum in spectra:
            phi = scipy.fft.irfftn(q_hat * spectrum[..., None], s=self._sizes, axes=axes)
            out.append(self._interp @ phi[crop].reshape(self.n_grid, k))
        return out


class ChunkedKernelSum:
    """sum_l p(x_k, x_l) v_l (and the row sums) a block of rows at a time, any d and kernel.

    For a `CuckerSmaleKernel` the block w_l / (alpha^2 + |x_k - x_l|^2) is built in place in a
    reused buffer of about `CACHE_BLOCK_ENTRIES` entries (cache-sized blocks: measured ~10x
    faster than `kernel.value` on large blocks); any other kernel goes through `kernel.value`
    on (B, 1, d) x (1, N, d) slices with B N <= `GENERIC_BLOCK_ENTRIES`.

    Args:
        kernel: an `InteractionKernel`.
        points: the positions (N, d).
        block: rows per block (0: chosen from N as above).
    """

    CACHE_BLOCK_ENTRIES = 2**17
    GENERIC_BLOCK_ENTRIES = 2**22

    def __init__(self, kernel: InteractionKernel, points: np.ndarray, block: int = 0) -> None:
        self.kernel = kernel
        self.points = np.asarray(points, dtype=float)
        n = self.points.shape[0]
        self._cucker_smale = isinstance(kernel, CuckerSmaleKernel)
        entries = self.CACHE_BLOCK_ENTRIES if self._cucker_smale else self.GENERIC_BLOCK_ENTRIES
        self.block = block if block > 0 else max(1, min(n, entries // n))

    def _blocks(self):
        x = self.points
        n = x.shape[0]
        if not self._cucker_smale:
            for lo in range(0, n, self.block):
                hi = min(lo + self.block, n)
                yield lo, hi, self.kernel.value(x[lo:hi, None, :], x[None, :, :])
            return
        coords = np.ascontiguousarray(x.T)  # (d, N)
        weights = self.kernel.weights  # a float or (N,)
        alpha2 = self.kernel.alpha**2
        denom = np.empty((self.block, n))
        diff = np.empty((self.block, n))
        for lo in range(0, n, self.block):
            hi = min(lo + self.block, n)
            dn, df = denom[: hi - lo], diff[: hi - lo]
            dn.fill(alpha2)
            for c in coords:
                np.subtract(c[None, :], c[lo:hi, None], out=df)
                np.multiply(df, df, out=df)
                dn += df
            yield lo, hi, np.divide(weights, dn, out=dn)

    def __call__(self, v: np.ndarray) -> np.ndarray:
        """P v for v (N, k); returns (N, k)."""
        out = np.empty((self.points.shape[0], v.shape[1]))
        for lo, hi, block in self._blocks():
            out[lo:hi] = block @ v
        return out

    def row_sums_and_product(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P 1 (N,), P v (N, k)) in one pass over the blocks."""
        n = self.points.shape[0]
        sums = np.empty(n)
        out = np.empty((n, v.shape[1]))
        for lo, hi, block in self._blocks():
            sums[lo:hi] = block.sum(axis=1)
            out[lo:hi] = block @ v
        return sums, out
