"""How fast is the compiled kernel pass, and its symmetric product, against numpy?

Question: per batch member (one swarm of N agents, d = 1), how much faster are the compiled
passes of `agent_envs.native.kernel` than the numpy they replace?

- the kernel pass (`cucker_smale_drift`: P's lower triangle p_kl = w / (alpha^2 +
  (x_l - x_k)^2), s = P 1 and L(x) x = (P x - s * x) / N) against the same in in-place numpy
  (preallocated buffers, one matmul P [x | 1]) and in plain numpy (with its temporaries);
- one symmetric product (`lower_product`: P q read from P's lower triangle only, the Lanczos
  phi-action's product) against numpy's ``P @ q``;
- two vectors' products in one pass over P (`lower_product_pair`, d > 1) against two
  `lower_product` passes, over one member's P in cache.

Baselines in the same run: the numpy passes above, interleaved rounds in one process, medians
of `--rounds`; the compiled calls are looped inside a numba function, `--members` members of
shape (N, N) (20: the paper's paths), for N in `--sizes`. Needs numba (the `fast` extra);
without it, or with AGENT_ENVS_NUMBA=0, the script says so and prints the numpy figures only.

    python benchmarks/bench_kernel_pass.py            # N = 30, 100, 300 (~30 s)
    python benchmarks/bench_kernel_pass.py --quick    # N = 100, 2 rounds (seconds)
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
from collections.abc import Callable
from typing import Any

import numpy as np
from _timing import ALPHA2, WEIGHT


def compiled_loops() -> dict[str, Callable[..., Any]]:
    """numba loops over the public kernel entry points: `reps` calls each (compiled here, not
    in the timed rounds)."""
    from numba import njit

    from agent_envs import native

    kernel = native.loaded("kernel")
    drift, product = kernel.cucker_smale_drift, kernel.lower_product
    pair = kernel.lower_product_pair

    @njit
    def passes(x: Any, p: Any, s: Any, f: Any, reps: int) -> None:
        for _ in range(reps):
            drift(x, WEIGHT, ALPHA2, p, s, f)

    @njit
    def products(p: Any, q: Any, w: Any, reps: int) -> None:
        n = p.shape[-1]
        for _ in range(reps):
            for b in range(p.shape[0]):
                product(p[b], q[b, 0], w[b, 0], n)

    @njit
    def singles(p: Any, q: Any, w: Any, reps: int) -> None:
        n = p.shape[-1]
        for _ in range(reps):
            for b in range(p.shape[0]):
                product(p[b], q[b, 0], w[b, 0], n)
                product(p[b], q[b, 1], w[b, 1], n)

    @njit
    def pairs(p: Any, q: Any, w: Any, reps: int) -> None:
        n = p.shape[-1]
        for _ in range(reps):
            for b in range(p.shape[0]):
                pair(p[b], q[b, 0], q[b, 1], w[b, 0], w[b, 1], n)

    return {"passes": passes, "products": products, "singles": singles, "pairs": pairs}


def per_member_us(n: int, members: int, rounds: int) -> dict[str, float]:
    """Microseconds per member of each pass at size `n` (medians of interleaved rounds); the
    pair and its two single passes over the first member's P only (in cache)."""
    from agent_envs import native
    from agent_envs.arrays import aligned_empty

    fns: dict[str, Callable[[], Any]] = {
        "plain pass": _timing.plain_kernel_drift(members, n),
        "in-place pass": _timing.inplace_kernel_drift(members, n),
    }
    rng = np.random.default_rng(0)
    p_full = rng.uniform(size=(members, n, n))
    p_full = p_full + np.swapaxes(p_full, -1, -2)
    q = rng.standard_normal((members, 2, n))
    fns["numpy P @ q"] = lambda: np.matmul(p_full, q[:, 0, :, None])
    per_call = dict.fromkeys(fns, members)  # member passes per call
    if native.available("kernel"):
        loops, reps = compiled_loops(), 20
        x = np.random.default_rng(0).uniform(-1.0, 1.0, (members, n, 1))
        p = aligned_empty((members, n, n))
        p[...] = p_full
        s, f, w = np.empty((members, n)), np.empty((members, n, 1)), np.empty((members, 2, n))
        one = p[:1]
        for name, call, count in (
            ("compiled pass", lambda: loops["passes"](x, p, s, f, reps), reps * members),
            ("lower_product", lambda: loops["products"](p, q, w, reps), reps * members),
            ("two lower_product", lambda: loops["singles"](one, q, w, 50 * reps), 50 * reps),
            ("lower_product_pair", lambda: loops["pairs"](one, q, w, 50 * reps), 50 * reps),
        ):
            call()  # (compiles)
            fns[name], per_call[name] = call, count
    seconds = _timing.interleaved(fns, 5, rounds)
    return {name: 1e6 * t / per_call[name] for name, t in seconds.items()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 100, 2 rounds")
    parser.add_argument("--sizes", type=int, nargs="+", default=None, help="N")
    parser.add_argument("--members", type=int, default=20, help="members per pass")
    parser.add_argument("--rounds", type=int, default=None, help="interleaved rounds")
    args = parser.parse_args()
    sizes = args.sizes or ([100] if args.quick else [30, 100, 300])
    rounds = args.rounds or (2 if args.quick else 7)
    print(f"Kernel pass per member, d = 1, {args.members} members, medians of {rounds} rounds")
    print(f"({_timing.compiled_paths()})\n")
    rows = []
    for n in sizes:
        us = per_member_us(n, args.members, rounds)
        if "compiled pass" not in us:
            rows.append((n, "(no compiled kernel pass here)", "", "", ""))
            continue
        rows.append((
            n,
            f"{us['in-place pass'] / us['compiled pass']:.2f}",
            f"{us['plain pass'] / us['compiled pass']:.2f}",
            f"{us['numpy P @ q'] / us['lower_product']:.2f}",
            f"{us['two lower_product'] / us['lower_product_pair']:.2f}",
        ))  # fmt: skip
    _timing.print_table(
        ("N", "in-place numpy / compiled pass", "plain numpy / compiled pass",
         "numpy P @ q / lower_product", "two lower_product / lower_product_pair"),
        rows,
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
