"""How fast is one env step at N = 100 against its compute floor, and SERB against EM?

Question: at the paper setting (`agent_envs/Swarm-v0`, N = 100, m = 50, 20 Brownian paths,
eps = 0.05, frozen Jacobian, max_control = 25), how close is an env step to the unavoidable
compute, the kernel matrix p_kl = w / (alpha^2 + (x_l - x_k)^2) and the drift
(P x - (P 1) * x) / N over x (20, 100, 1), and what does the stiff integrator (SERB) cost
against Euler-Maruyama (EM)?

Baselines in the same run (one process, interleaved rounds, medians of `--rounds`):

- EM env step / that floor written as plain numpy (with its temporaries), as in-place numpy
  (preallocated buffers, one matmul P [x | 1]) and as the env's own kernel pass (compiled with
  numba where it serves, else the in-place numpy);
- SERB env step / EM env step (the paper env, resets with seeds 0, 1, ... inside the timing);
- one bare SERB `integrator.step` / one bare EM step (N = 100, 1 path, zero control);
- SERB / EM in a native vector env of 16 paper envs (320 systems a step: compute-bound);
- with numba: the compiled calls' share of each env step (timers around the public entry
  points of `agent_envs.native`) and SERB / EM with no interpreter time beyond EM's,
  (EM step + SERB's compiled time - EM's) / EM step, and of the compiled calls alone.

    python benchmarks/bench_step_floor.py            # 5 rounds of 100 calls (~1 min)
    python benchmarks/bench_step_floor.py --quick    # 2 rounds of 10 calls (seconds)
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse

import numpy as np
from _timing import env_kwargs


def step_ratios(calls: int, rounds: int) -> dict[str, float]:
    """Seconds per call of each side, interleaved in one process (medians)."""
    fns = {
        "serb_env": _timing.single_env_stepper(env_kwargs("paper", "serb")),
        "em_env": _timing.single_env_stepper(env_kwargs("paper", "em")),
        "serb_native": _timing.native_stepper(env_kwargs("paper", "serb"), 16),
        "em_native": _timing.native_stepper(env_kwargs("paper", "em"), 16),
        "plain": _timing.plain_kernel_drift(),
        "inplace": _timing.inplace_kernel_drift(),
        "floor": _timing.kernel_drift_floor(20),
        "serb_bare_1": _timing.bare_stepper("serb", 1),
        "em_bare_1": _timing.bare_stepper("em", 1),
    }
    out = _timing.interleaved(fns, calls, rounds)
    shares: dict[str, list[dict[str, float]]] = {"serb": [], "em": []}
    for _ in range(rounds):  # SERB and EM in alternating rounds (one machine speed)
        for name in shares:
            shares[name].append(_timing.compiled_share(fns[f"{name}_env"], calls, 1))
    for name, found in shares.items():
        if found[0]:
            for key in ("total", "compiled"):
                out[f"{name}_{key}"] = float(np.median([f[key] for f in found]))
    out["plan_serb"] = fns["serb_env"].env.plan.describe()  # type: ignore[attr-defined]
    return out


RATIOS = (
    ("EM env step / plain numpy kernel + drift", "em_env", "plain"),
    ("EM env step / in-place numpy kernel + drift", "em_env", "inplace"),
    ("EM env step / the env's kernel pass", "em_env", "floor"),
    ("SERB env step / EM env step", "serb_env", "em_env"),
    ("one bare SERB step / one bare EM step (N = 100, 1 path)", "serb_bare_1", "em_bare_1"),
    ("SERB / EM, native vector env of 16 paper envs", "serb_native", "em_native"),
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 rounds of 10 calls")
    parser.add_argument("--rounds", type=int, default=None, help="interleaved rounds (medians)")
    parser.add_argument("--calls", type=int, default=None, help="calls per round")
    args = parser.parse_args()
    rounds = args.rounds or (2 if args.quick else 5)
    calls = args.calls or (10 if args.quick else 100)
    res = step_ratios(calls, rounds)
    print(f"Env step against its floor, paper setting, medians of {rounds} rounds")
    print(f"({_timing.compiled_paths()}; SERB env: {res['plan_serb']})\n")
    _timing.print_table(
        ("ratio (same process)", "value"),
        [(label, f"{res[num] / res[den]:.2f}") for label, num, den in RATIOS],
    )
    if "serb_compiled" in res:
        serb, em = res["serb_total"], res["em_total"]
        no_interpreter = (em + res["serb_compiled"] - res["em_compiled"]) / em
        print(
            f"Compiled calls' share of the env step: SERB {100 * res['serb_compiled'] / serb:.0f}"
            f" %, EM {100 * res['em_compiled'] / em:.0f} % (alternating rounds). SERB / EM with"
            f" no interpreter time beyond EM's: {no_interpreter:.2f}; the compiled calls alone:"
            f" {res['serb_compiled'] / res['em_compiled']:.2f}\n"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
