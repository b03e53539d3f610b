"""Which batch sizes `torch.linalg.eigh` (cuSOLVER) takes on a CUDA device, one call each.

The Lanczos phi-action diagonalizes one small tridiagonal T_m per system: the paper's SERB at
4096 envs x 20 paths asks for batches of 81 920 (m x m) matrices, and one such call failed with
CUSOLVER_STATUS_INTERNAL_ERROR on an H100. This prints, for each size m, each batch size and
whether one call ran (and its seconds); `agent_envs.arrays.eigh` splits CUDA batches above
`CUDA_EIGH_MAX_BATCH`. Matrices: symmetric tridiagonal with entries from a seeded generator.

    python benchmarks/probe_cuda_eigh.py [--device cuda]
"""

from __future__ import annotations

import argparse
import time

import torch


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--sizes", type=int, nargs="+", default=[3, 8, 16, 27])
    parser.add_argument(
        "--batches", type=int, nargs="+", default=[4096, 8192, 16384, 32768, 65536, 81920]
    )
    args = parser.parse_args()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        print(f"{args.device}: torch sees no CUDA device here")
        return 0
    gen = torch.Generator(device=args.device).manual_seed(0)
    print(f"torch {torch.__version__} on {torch.cuda.get_device_name(args.device)}\n")
    print("| m | " + " | ".join(f"B = {b}" for b in args.batches) + " |")
    print("|---" * (len(args.batches) + 1) + "|")
    for m in args.sizes:
        cells = []
        for b in args.batches:
            diag = torch.randn((b, m), generator=gen, device=args.device, dtype=torch.float64)
            off = torch.rand((b, m - 1), generator=gen, device=args.device, dtype=torch.float64)
            t = torch.diag_embed(diag) + torch.diag_embed(off, 1) + torch.diag_embed(off, -1)
            try:
                torch.cuda.synchronize()
                start = time.perf_counter()
                torch.linalg.eigh(t)
                torch.cuda.synchronize()
                cells.append(f"{1e3 * (time.perf_counter() - start):.1f} ms")
            except RuntimeError as err:
                cells.append("fails: " + str(err).split(",")[0][:40])
                torch.cuda.synchronize()
            del t
        print(f"| {m} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
