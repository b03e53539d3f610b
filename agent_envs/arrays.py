"""Array libraries behind one dispatch: numpy (the default) and torch (CPU/CUDA, differentiable).

The numerical core (kernels, drift, Jacobians, phi-functions, integrators, costs, simulate) is
written once against the Python Array API standard: every function asks `namespace(x, ...)`
for the module `xp` of its arguments and calls ``xp.exp``, ``xp.linalg.eigh``, ``xp.concat``...
For numpy arrays that module is numpy itself (numpy >= 2 implements the standard in its main
namespace, and its plain functions carry the least per-call overhead); for torch tensors it is
`array_api_compat.torch`. Mixing the two in one call is an error of the caller.

The few pieces the standard lacks or where the libraries differ live here and nowhere else:

- `expm`: `scipy.linalg.expm` (Pade, scaling and squaring) vs `torch.linalg.matrix_exp`.
- `eigh`: `xp.linalg.eigh`, on CUDA in batches of at most `CUDA_EIGH_MAX_BATCH` matrices
  (cuSOLVER's batched solver failed with an internal error on one call of 81 920 small
  matrices: the paper's SERB at 4096 envs x 20 paths).
- `symmetric_function_action`: f(A) V = Q f(Lambda) Q^T V for a symmetric A. On torch with
  autograd it is a custom `torch.autograd.Function` whose backward uses the Daleckii-Krein
  formula with divided differences of f, so the gradient stays finite at repeated eigenvalues
  (where `torch.linalg.eigh`'s own backward divides by lambda_i - lambda_j = 0; the frozen
  L(x) of a swarm at consensus has an (N-1)-fold eigenvalue).
- `subtract_diagonal`: P - diag(s), in place on a fresh numpy array, functional on torch.
- conversions (`asarray`, `to_numpy`) and the choice of library and device (`resolve`).
- `hot_path_threads`: the BLAS thread pools limited to `HOT_PATH_BLAS_THREADS` (1) while the core
  steps, restored afterwards. The core's matrices are small (N x N, N ~ 100): with more than one
  BLAS thread per process, several processes on a loaded machine oversubscribe the cores and every
  small product waits for its threads (docs/benchmarks.md, "BLAS threads", has the measurement:
  benchmarks/bench_blas_threads.py). threadpoolctl (the library scikit-learn uses for the same job)
  finds the BLAS libraries numpy and scipy loaded; one controller is built on first use and only the
  pools whose size differs are touched, so a call costs a few microseconds. torch's own intra-op
  pool is left alone.

torch is imported lazily, only when a torch tensor is seen or a torch backend is asked for:
`import agent_envs` and every numpy call leave it unimported.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import scipy.linalg
from array_api_compat import is_torch_array

#: The array libraries `resolve` accepts.
BACKENDS = ("numpy", "torch")

#: BLAS threads inside `hot_path_threads` (None: leave the pools as they are).
HOT_PATH_BLAS_THREADS: int | None = 1
_BLAS_LIBRARIES: list[Any] | None = None


def _blas_libraries() -> list[Any]:
    global _BLAS_LIBRARIES
    if _BLAS_LIBRARIES is None:
        from threadpoolctl import ThreadpoolController

        controller = ThreadpoolController()
        _BLAS_LIBRARIES = [lib for lib in controller.lib_controllers if lib.user_api == "blas"]
    return _BLAS_LIBRARIES


def prepare_hot_path() -> None:
    """Find the BLAS pools `hot_path_threads` limits now rather than at the first step.

    threadpoolctl scans every loaded library (about 10 ms, once per process); an env calls this
    when it is made, so that its first step costs what the others do.
    """
    if HOT_PATH_BLAS_THREADS is not None:
        _blas_libraries()


@contextmanager
def hot_path_threads() -> Iterator[None]:
    """Limit the BLAS pools to `HOT_PATH_BLAS_THREADS` inside the block; restore them after.

    Set `agent_envs.arrays.HOT_PATH_BLAS_THREADS = None` to keep your own thread settings.
    """
    limit = HOT_PATH_BLAS_THREADS
    changed = []
    if limit is not None:
        for lib in _blas_libraries():
            before = lib.get_num_threads()
            if before != limit:
                lib.set_num_threads(limit)
                changed.append((lib, before))
    try:
        yield
    finally:
        for lib, before in changed:
            lib.set_num_threads(before)


_NUMPY_XP: Any = np
if int(np.__version__.split(".")[0]) < 2:  # numpy 1.x: the standard through the compat layer
    import array_api_compat.numpy as _compat_numpy

    _NUMPY_XP = _compat_numpy


def _torch_xp() -> Any:
    import array_api_compat.torch as xp_torch

    return xp_torch


def is_torch(x: Any) -> bool:
    """True for a torch tensor (never imports torch)."""
    if type(x) is np.ndarray:  # (the hot path's answer, without the module lookup)
        return False
    return sys.modules.get("torch") is not None and is_torch_array(x)


def namespace(*arrays: Any) -> Any:
    """The Array API namespace of `arrays` (None and Python scalars are ignored).

    numpy (itself) when no torch tensor is among them, `array_api_compat.torch` otherwise.
    """
    for a in arrays:
        if type(a) is not np.ndarray and is_torch(a):
            return _torch_xp()
    return _NUMPY_XP


def is_numpy_namespace(xp: Any) -> bool:
    return xp is _NUMPY_XP


def resolve(backend: str | None, device: Any, *arrays: Any) -> tuple[Any, Any, Any]:
    """(xp, device, dtype) for a computation given a requested backend/device and its inputs.

    `backend` None picks torch when one of `arrays` is a torch tensor or a `device` is given,
    numpy otherwise. The dtype is float64, or the floating dtype of the first torch tensor in
    `arrays`. Raises ValueError naming `backend`/`device` on a bad choice.
    """
    if backend is not None and backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS} or None, got {backend!r}")
    tensors = [a for a in arrays if is_torch(a)]
    if backend is None:
        backend = "torch" if tensors or device is not None else "numpy"
    if backend == "numpy":
        if tensors:
            raise ValueError("backend='numpy' was asked for, but torch tensors were passed in")
        if device not in (None, "cpu"):
            raise ValueError(f"device must be None or 'cpu' with backend='numpy', got {device!r}")
        return _NUMPY_XP, None, np.float64
    try:
        import torch
    except ImportError:  # pragma: no cover - depends on the install
        raise ValueError(
            "backend='torch' needs torch installed (pip install 'agent-envs[train]')"
        ) from None
    dtype = torch.float64
    for t in tensors:
        if t.is_floating_point():
            dtype = t.dtype
            break
    if device is None:
        device = tensors[0].device if tensors else torch.device("cpu")
    else:
        try:
            device = torch.device(device)
        except (RuntimeError, TypeError) as exc:
            raise ValueError(f"device must name a torch device, got {device!r}: {exc}") from None
    return _torch_xp(), device, dtype


def asarray(obj: Any, like: Any = None, *, xp: Any = None, device: Any = None, dtype: Any = None):
    """`obj` as an array of the library, device and floating dtype of `like` (or of xp/device).

    numpy inputs to a torch target are copied onto the device; a torch tensor already there is
    returned unchanged (autograd history kept).
    """
    if like is not None:
        xp = namespace(like)
        if is_torch(like):
            device, dtype = like.device, (dtype or like.dtype)
    if xp is None or is_numpy_namespace(xp):
        return np.asarray(obj, dtype=dtype or np.float64)
    import torch

    if is_torch(obj):
        return obj.to(device=device, dtype=dtype or obj.dtype)
    return torch.as_tensor(np.asarray(obj), dtype=dtype or torch.float64, device=device)


def to_numpy(x: Any) -> np.ndarray:
    """A numpy copy/view of an array of either library (detached from autograd)."""
    if is_torch(x):
        return x.detach().cpu().numpy()
    return np.asarray(x)


#: Byte alignment of the hot path's large workspaces (`aligned_empty`): a cache line, so that
#: no 32- or 64-byte vector load of a row crosses one where the row itself starts aligned.
WORKSPACE_ALIGNMENT = 64


def aligned_empty(shape: tuple[int, ...], alignment: int = WORKSPACE_ALIGNMENT) -> np.ndarray:
    """An uninitialized C-contiguous float64 array of `shape` whose data starts at a multiple of
    `alignment` bytes (a multiple of 8): a view into a slightly larger buffer.

    numpy aligns large allocations to 16 bytes only (glibc's mmap'd chunks start 16 bytes into
    a page), so a (..., 100, 100) kernel matrix began at 16 mod 64 and half of the 32-byte
    loads of its rows crossed a cache line: the compiled Lanczos product over such a P took
    0.88-0.93 us against 0.80-0.82 us at 64-byte alignment (N = 100, a microbenchmark over
    base offsets 0 to 4096, benchmarks/bench_step_floor.py for the env)."""
    if alignment % 8:
        raise ValueError(f"alignment must be a multiple of 8 bytes, got {alignment}")
    size = math.prod(shape)
    raw = np.empty(size + alignment // 8, dtype=np.float64)
    start = (-raw.ctypes.data % alignment) // 8
    return raw[start : start + size].reshape(shape)


def _real_floating(a: Any) -> bool:
    if is_torch(a):
        return bool(a.is_floating_point())
    return getattr(a, "dtype", None) is not None and a.dtype.kind == "f"


def sum_axis(a: Any, axis: int) -> Any:
    """xp.sum(a, axis=axis), the same values bit for bit and the same dtype, for numpy arrays
    and torch tensors (real floating ones take the path below; others xp.sum itself).

    An axis of length 1 (d = 1, one path) is taken as a + 0.0 with the axis dropped (numpy's
    reduction adds the one entry to its identity: -0.0 becomes +0.0, as here): an element-wise
    pass instead of a reduction that pays its loop overhead per output element (on a (256, 1,
    100, 1) array: 24 us for numpy's sum over the last axis, 48 us for its mean over the
    paths, 13 us as a + 0.0)."""
    return _reduce_axis(a, axis, "sum")


def mean_axis(a: Any, axis: int) -> Any:
    """xp.mean(a, axis=axis), the same values bit for bit and the same dtype (the sum over one
    entry divided by 1 is `sum_axis`'s a + 0.0), for numpy arrays and torch tensors (real
    floating ones; others xp.mean itself)."""
    return _reduce_axis(a, axis, "mean")


def _reduce_axis(a: Any, axis: int, reduction: str) -> Any:
    """xp.sum or xp.mean (`reduction`) over `axis`; over one entry of a real floating array,
    that entry + 0 in a's own dtype, a new array (numpy 1.x would promote a 0-d float32 + 0.0).
    A numpy array takes the same calls without the namespace's dispatch."""
    if type(a) is np.ndarray:
        if a.shape[axis] == 1 and a.dtype.kind == "f":
            one = a.squeeze(axis)
            return np.add(one, 0.0, dtype=one.dtype)
        return getattr(_NUMPY_XP, reduction)(a, axis=axis)
    xp = namespace(a)
    if a.shape[axis] == 1 and _real_floating(a):
        one = xp.squeeze(a, axis=axis)
        return np.add(one, 0.0, dtype=one.dtype) if isinstance(one, np.ndarray) else one + 0.0
    return getattr(xp, reduction)(a, axis=axis)


def zeros(shape: tuple[int, ...], like: Any) -> Any:
    """Zeros of `shape` in the library, device and dtype of `like`."""
    if is_torch(like):
        import torch

        return torch.zeros(shape, dtype=like.dtype, device=like.device)
    return np.zeros(shape, dtype=np.result_type(like, np.float64))


def expm(a: Any) -> Any:
    """The matrix exponential of a batch (..., n, n)."""
    if is_torch(a):
        import torch

        return torch.linalg.matrix_exp(a)
    return scipy.linalg.expm(a)


#: At most this many matrices per `torch.linalg.eigh` call on CUDA (`eigh`). cuSOLVER's batched
#: eigensolver (`cusolverDnXsyevBatched`) raised CUSOLVER_STATUS_INTERNAL_ERROR on an H100
#: (torch 2.11, CUDA 13) for one batch of 81 920 Lanczos tridiagonals (4096 envs x 20 paths).
#: benchmarks/probe_cuda_eigh.py: batches of 4096-32 768 (m x m) tridiagonals ran and 65 536
#: failed, for every m of 3-27 (the probe's 100 s ran out at m = 33: not measured). 4096 is what
#: the GPU table of docs/benchmarks.md ran with; the time is linear in the batch, so the split
#: costs only its launches.
CUDA_EIGH_MAX_BATCH = 4096


def eigh(a: Any) -> tuple[Any, Any]:
    """Eigenvalues (..., n) ascending and eigenvectors (..., n, n) of a symmetric batch
    (..., n, n): `xp.linalg.eigh`, on a CUDA tensor in batches of at most
    `CUDA_EIGH_MAX_BATCH` matrices (each matrix's result does not depend on its batch)."""
    if not is_torch(a) or a.device.type != "cuda" or a.ndim < 3:
        return namespace(a).linalg.eigh(a)
    import torch

    batch = a.shape[:-2]
    flat = a.reshape(-1, *a.shape[-2:])
    if flat.shape[0] <= CUDA_EIGH_MAX_BATCH:
        return torch.linalg.eigh(a)
    parts = [torch.linalg.eigh(chunk) for chunk in flat.split(CUDA_EIGH_MAX_BATCH)]
    lam = torch.cat([part[0] for part in parts]).reshape(*batch, a.shape[-1])
    q = torch.cat([part[1] for part in parts]).reshape(a.shape)
    return lam, q


def tridiagonal(diag: Any, off: Any) -> Any:
    """The symmetric tridiagonal T (..., m, m) with diagonal `diag` (..., m) and off-diagonal
    `off` (..., m - 1)."""
    m = diag.shape[-1]
    if is_torch(diag):
        import torch

        t = torch.diag_embed(diag)
        if m > 1:
            t = t + torch.diag_embed(off, offset=1) + torch.diag_embed(off, offset=-1)
        return t
    t = np.zeros((*diag.shape, m), dtype=np.result_type(diag, np.float64))
    idx = np.arange(m)
    t[..., idx, idx] = diag
    t[..., idx[:-1], idx[1:]] = off
    t[..., idx[1:], idx[:-1]] = off
    return t


def divide_fresh(p: Any, c: float) -> Any:
    """p / c, in place for a fresh numpy array (saves a large temporary), functional on torch."""
    if is_torch(p):
        return p / c
    return np.divide(p, c, out=p)


def add_diagonal_blocks(blocks: Any, diag: Any) -> Any:
    """blocks[..., k, k, :, :] += diag[..., k, :, :] for blocks (..., N, N, d, d): in place on a
    fresh numpy array, functional on torch."""
    n = blocks.shape[-3]
    if is_torch(blocks):
        import torch

        eye = torch.eye(n, dtype=blocks.dtype, device=blocks.device)
        return blocks + eye[..., None, None] * diag[..., :, None, :, :]
    idx = np.arange(n)
    blocks[..., idx, idx, :, :] += diag
    return blocks


def subtract_diagonal(p: Any, s: Any) -> Any:
    """P - diag(s) for P (..., n, n) and s (..., n). Modifies a numpy P in place (callers pass a
    fresh array); functional on torch so autograd sees it."""
    if is_torch(p):
        import torch

        return p - torch.diag_embed(s)
    n = p.shape[-1]
    idx = np.arange(n)
    p[..., idx, idx] -= s
    return p


def symmetric_function_action(
    a: Any,
    v: Any,
    f: Callable[[Any], Any],
    df: Callable[[Any], Any],
) -> Any:
    """f(A) V = Q f(Lambda) Q^T V for symmetric A (..., n, n) and V (..., n, k).

    A is symmetrized, (A + A^T)/2, before its eigendecomposition A = Q Lambda Q^T, so the
    result is a function of the symmetric part only. `f` maps eigenvalues to f(lambda)
    elementwise, `df` to f'(lambda); both take and return arrays of the same library.

    Gradient (torch): with G = dL/dY, Y = f(A) V,
        dL/dV = f(A) G,
        dL/dA = sym(Q (F o (Q^T G V^T Q)) Q^T),
    F_ij = (f(lambda_i) - f(lambda_j)) / (lambda_i - lambda_j), and f'((lambda_i + lambda_j)/2)
    when |lambda_i - lambda_j| <= 1e-6 max(1, |lambda_i|, |lambda_j|) (Daleckii-Krein; the
    midpoint derivative is the divided difference up to O(delta^2 f''')).
    """
    if is_torch(a) or is_torch(v):
        import torch

        if torch.is_grad_enabled() and (a.requires_grad or v.requires_grad):
            return _symmetric_action_function().apply(a, v, f, df)
    return eigh_function_action(a, v, f)[0]


def eigh_function_action(a: Any, v: Any, f: Callable[[Any], Any]) -> tuple[Any, tuple[Any, Any]]:
    """f(A) V = Q f(Lambda) Q^T V for symmetric A (..., n, n), V (..., n, k), without autograd
    (`symmetric_function_action`'s forward), and the decomposition (Lambda, Q) of the
    symmetrized A it came from, for callers that read it too."""
    xp = namespace(a, v)
    a = 0.5 * (a + xp.matrix_transpose(a))
    lam, q = eigh(a)
    coef = xp.matrix_transpose(q) @ v
    return q @ (f(lam)[..., None] * coef), (lam, q)


#: Relative gap below which two eigenvalues count as equal in the divided differences.
DIVIDED_DIFFERENCE_TOL = 1e-6


def divided_differences(lam: Any, f_lam: Any, df: Callable[[Any], Any]) -> Any:
    """F_ij = (f(l_i) - f(l_j)) / (l_i - l_j), f'((l_i + l_j)/2) for close l: (..., n, n)."""
    xp = namespace(lam)
    li, lj = lam[..., :, None], lam[..., None, :]
    gap = li - lj
    scale = xp.maximum(xp.maximum(xp.abs(li), xp.abs(lj)), xp.ones_like(gap))
    close = xp.abs(gap) <= DIVIDED_DIFFERENCE_TOL * scale
    quotient = (f_lam[..., :, None] - f_lam[..., None, :]) / xp.where(close, 1.0, gap)
    return xp.where(close, df(0.5 * (li + lj)), quotient)


_FUNCTION_CLASS: Any = None


def _symmetric_action_function() -> Any:
    """The torch.autograd.Function of `symmetric_function_action` (built on first use)."""
    global _FUNCTION_CLASS
    if _FUNCTION_CLASS is not None:
        return _FUNCTION_CLASS
    import torch
    from torch.autograd.function import once_differentiable

    class SymmetricFunctionAction(torch.autograd.Function):
        @staticmethod
        def forward(ctx, a, v, f, df):
            a_sym = 0.5 * (a + a.mT)
            lam, q = eigh(a_sym)
            f_lam = f(lam)
            coef = q.mT @ v
            ctx.save_for_backward(lam, q, f_lam, coef)
            ctx.df = df
            ctx.shapes = (a.shape, v.shape)
            return q @ (f_lam[..., None] * coef)

        @staticmethod
        @once_differentiable
        def backward(ctx, grad):
            lam, q, f_lam, coef = ctx.saved_tensors
            a_shape, v_shape = ctx.shapes
            qg = q.mT @ grad  # Q^T G
            grad_a = grad_v = None
            if ctx.needs_input_grad[1]:
                grad_v = (q @ (f_lam[..., None] * qg)).sum_to_size(v_shape)
            if ctx.needs_input_grad[0]:
                dd = divided_differences(lam, f_lam, ctx.df)
                inner = dd * (qg @ coef.mT)  # F o (Q^T G V^T Q)
                grad_a = q @ inner @ q.mT
                grad_a = (0.5 * (grad_a + grad_a.mT)).sum_to_size(a_shape)
            return grad_a, grad_v, None, None

    _FUNCTION_CLASS = SymmetricFunctionAction
    return _FUNCTION_CLASS
