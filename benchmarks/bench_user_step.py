"""How fast is the env users actually step, against the compiled work of the same step?

Question: at the paper setting (`agent_envs/Swarm-v0`, SERB, N = 100, m = 50, eps = 0.05,
alpha = 0.1, sigma = 0.01, T = 1, target 0.7, frozen Jacobian, max_control = 25, one path,
one thread), how much slower is a step of the env a user makes, `gym.make` with its default
wrappers or the PettingZoo parallel env, than the same step inside the native vector env's
batch (B = 64), where the interpreter's share is spread over 64 envs; and what does PPO get
end to end on each vector env?

Floors in the same run (each step figure is a ratio of two sides timed in one fresh process,
interleaved rounds of about `--seconds` each, medians of `--rounds`; the table gives the median
over `--processes` fresh processes):

1. the `gym.make` env step (OrderEnforcing > PassiveEnvChecker > TimeLimit > SwarmEnv) / the
   native env's per-env step, `gym.make_vec(..., vectorization_mode="vector_entry_point")`
   at B = 64 (its batch step / 64); the bare `SwarmEnv` (no wrapper) / the same floor; each
   wrapper's share of the `gym.make` step (the wrapper alone around a stub env that costs
   nothing, minus the stub, over the `gym.make` step: a difference of two envs' steps would
   drown a microsecond in their noise);
2. the PettingZoo parallel env step (`agent_envs.swarm_v0.parallel_env`) at N = 100 / the same
   floor, and at N = 10 / the native per-env step at N = 10; PettingZoo's API alone as a second
   floor: building the five dicts of N entries a step returns (observations, rewards,
   terminations, truncations, infos with the env's three keys), timed on its own;
3. the `gym.make` env with 20 paths / the native per-env step with 20 paths (B = 64);
4. SB3 PPO end to end (`MlpPolicy`, SB3's defaults but n_steps, sized for the budget): swarm
   env-steps/s of `model.learn` on `DummyVecEnv` of `gym.make` envs and on `NativeVecEnv`, each
   in its own fresh process; the floor is the same vector env stepped alone for as many steps
   (the env's share of `learn`);
5. parameter-shared PPO through SuperSuit (one sub-env per agent, the builder `agent-envs
   train` uses; batch 640 as `training/hyperparams/ppo.yml`), the same figures.

Cold: the first `--cold-steps` (50) steps of a `gym.make` env, the first thing a fresh process
steps, over the same steps of a new env once the process is warm (median of `--rounds` envs).

A/B: `--baseline-python PY` runs every fresh process also with the interpreter PY (say the venv
of an older checkout; this script and its helpers run there against that checkout's
`agent_envs`), alternating the two within each round, and adds old / new seconds of each user
step and new / old env-steps/s of each PPO run. Two runs of one tree read 0.8-1.25 on the PPO
rows on a shared 2-core machine: use `--processes 5` or more to see a change under 1.5x.

    python benchmarks/bench_user_step.py              # 3 processes, ~2 min (A/B: ~5 min)
    python benchmarks/bench_user_step.py --quick      # 1 process, tiny PPO budgets (~30 s)
    python benchmarks/bench_user_step.py --baseline-python OLD/.venv/bin/python --json out.json
"""

from __future__ import annotations

import _timing  # isort: skip  (first: pins the BLAS pools before numpy loads)

import argparse
import json
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np

#: the paper setting, one path (the env's default), SERB with the frozen Jacobian
PAPER: dict[str, Any] = {
    "n_agents": 100, "n_steps": 50, "epsilon": 0.05, "alpha": 0.1, "sigma": 0.01,
    "horizon": 1.0, "target": 0.7, "integrator": "serb", "jacobian": "frozen",
    "max_control": 25.0,
}  # fmt: skip
#: envs in the native vector env whose per-env step is the floor
BATCH = 64
#: --quick -> (vector env, envs, n_steps, budget in swarm env-steps, batch_size) of the PPO runs
PPO_RUNS = {
    False: (("dummy", 4, 512, 4096, None), ("native", 4, 512, 4096, None),
            ("supersuit", 1, 128, 256, 640)),
    True: (("dummy", 4, 16, 128, None), ("native", 4, 16, 128, None),
           ("supersuit", 1, 32, 64, 640)),
}  # fmt: skip


def paper(**extra: Any) -> dict[str, Any]:
    """The paper setting's `gym.make` keyword arguments with `extra` replaced."""
    return {**PAPER, **extra}


# ----------------------------------------------------------------------------- steppers
def wrapper_chain(kwargs: dict[str, Any]) -> list[Any]:
    """`gym.make`'s env and each wrapper inside it, outermost first, down to the bare env."""
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers the id)
    from agent_envs.envs import ENV_ID

    chain = [gym.make(ENV_ID, **kwargs)]
    while isinstance(chain[-1], gym.Wrapper):
        chain.append(chain[-1].env)
    return chain


def level_stepper(kwargs: dict[str, Any], depth: int) -> Callable[[], None]:
    """One step per call of a fresh `gym.make` env entered `depth` wrappers in (0: the env a
    user gets, -1: the bare `SwarmEnv`), fixed action (uniform in [-0.5, 0.5],
    default_rng(1)); at an episode's end a reset at the same level with the next seed (inside
    the timing)."""
    env = wrapper_chain(kwargs)[depth]
    action = np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape)
    action = action.astype(np.float32)
    state = {"seed": 0}
    env.reset(seed=0)

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            state["seed"] += 1
            env.reset(seed=state["seed"])

    return step


def parallel_stepper(kwargs: dict[str, Any]) -> Callable[[], None]:
    """One PettingZoo parallel env step per call, fixed actions (agent k's the k-th of
    default_rng(1)'s uniform draws in [-0.5, 0.5], float32 arrays (1,)); at the episode's end
    (no live agents) a reset with the next seed, inside the timing."""
    from agent_envs import swarm_v0

    env = swarm_v0.parallel_env(**kwargs)
    draws = batch_row(len(env.possible_agents))
    actions = {agent: draws[k : k + 1] for k, agent in enumerate(env.possible_agents)}
    state = {"seed": 0}
    env.reset(seed=0)

    def step() -> None:
        env.step(actions)
        if not env.agents:
            state["seed"] += 1
            env.reset(seed=state["seed"])

    return step


def batch_row(n: int) -> np.ndarray:
    """The native env's fixed actions of its first env: (n,) float32 (`_timing.batch_actions`)."""
    return _timing.batch_actions(1, n)[0]


def api_dicts(kwargs: dict[str, Any]) -> Callable[[], Any]:
    """PettingZoo's API alone: the five dicts of N entries a parallel env step returns, built
    from arrays a step has (observation rows (N, 4), rewards and running costs (N,)), with the
    env's agent names and the env's info keys (time, running_cost, diverged)."""
    from agent_envs import swarm_v0

    agents = list(swarm_v0.parallel_env(**kwargs).possible_agents)
    n = len(agents)
    rows = np.zeros((n, 4), dtype=np.float32)
    rewards, costs = np.full(n, -0.01), np.full(n, 0.01)

    def build() -> tuple[dict[str, Any], ...]:
        observations = dict(zip(agents, rows, strict=True))
        reward = {a: float(r) for a, r in zip(agents, rewards, strict=True)}
        terminations = dict.fromkeys(agents, False)
        truncations = dict.fromkeys(agents, False)
        infos = {
            a: {"time": 0.5, "running_cost": float(c), "diverged": False}
            for a, c in zip(agents, costs, strict=True)
        }
        return observations, reward, terminations, truncations, infos

    return build


def wrapper_steppers(kwargs: dict[str, Any]) -> dict[str, Callable[[], Any]]:
    """Each of `gym.make`'s wrappers alone around a stub env that costs nothing (the swarm
    env's spaces, `step` returns one stored tuple): "stub" and "stub_<Wrapper>"; a wrapper's
    cost per step is its stepper's time minus the stub's."""
    import gymnasium as gym
    from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker, TimeLimit

    swarm = wrapper_chain(kwargs)[-1]
    observation, _ = swarm.reset(seed=0)
    action = batch_row(swarm.action_space.shape[0])

    class StubEnv(gym.Env):
        """The swarm env's spaces; reset and step return stored values."""

        observation_space, action_space = swarm.observation_space, swarm.action_space

        def reset(self, *, seed: int | None = None, options: dict | None = None) -> Any:
            super().reset(seed=seed)
            return observation, {}

        def step(self, action: Any) -> Any:
            return observation, 0.0, False, False, {}

    wrappers = {
        "TimeLimit": lambda env: TimeLimit(env, max_episode_steps=2**62),
        "PassiveEnvChecker": PassiveEnvChecker,
        "OrderEnforcing": OrderEnforcing,
    }
    envs = {"stub": StubEnv(), **{f"stub_{n}": w(StubEnv()) for n, w in wrappers.items()}}
    for env in envs.values():
        env.reset(seed=0)
    return {name: partial(env.step, action) for name, env in envs.items()}


def user_steppers() -> tuple[dict[str, Callable[[], Any]], dict[str, int]]:
    """The timed functions (name -> function) and the env-steps of one call of each."""
    fns: dict[str, Callable[[], Any]] = {
        "gym": level_stepper(paper(), 0),
        "bare": level_stepper(paper(), -1),
        **wrapper_steppers(paper()),
        "native": _timing.native_stepper(paper(), BATCH),
        "parallel": parallel_stepper(paper()),
        "dicts": api_dicts(paper()),
        "native_10": _timing.native_stepper(paper(n_agents=10), BATCH),
        "parallel_10": parallel_stepper(paper(n_agents=10)),
        "dicts_10": api_dicts(paper(n_agents=10)),
        "gym_20": level_stepper(paper(n_paths=20), 0),
        "native_20": _timing.native_stepper(paper(n_paths=20), BATCH),
    }
    per_call = {name: BATCH if name.startswith("native") else 1 for name in fns}
    return fns, per_call


# ----------------------------------------------------------------------------- workers
def first_steps(steps: int) -> float:
    """Seconds per step of the first `steps` steps of a new `gym.make` env (seeds 0, 1, ...)."""
    step = level_stepper(paper(), 0)
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return (time.perf_counter() - start) / steps


def worker_steps(seconds: float, rounds: int, cold_steps: int) -> dict[str, Any]:
    """In a fresh process: seconds per step of the first `cold_steps` steps of a `gym.make`
    env, the first thing the process steps ("cold"), and of the same steps of a new env once
    the process is warm ("warm_first", the median of `rounds` envs); seconds per env-step of
    every stepper ("warm", medians of interleaved rounds); `gym.make`'s chain of wrappers
    (class names, outermost first)."""
    cold = first_steps(cold_steps)
    fns, per_call = user_steppers()
    chain = [type(level).__name__ for level in wrapper_chain(paper())]
    warm = _timing.interleaved_for(fns, seconds, rounds)
    warm = {name: t / per_call[name] for name, t in warm.items()}
    warm_first = float(np.median([first_steps(cold_steps) for _ in range(rounds)]))
    return {"warm": warm, "cold": cold, "warm_first": warm_first, "chain": chain}


def worker_ppo(
    vec_env: str, n_envs: int, n_steps: int, env_steps: int, batch_size: int | None
) -> dict[str, float]:
    """In a fresh process: `_ppo_timing.ppo_rates` of one vector env at the paper setting."""
    import _ppo_timing

    return _ppo_timing.ppo_rates(vec_env, paper(), n_envs, n_steps, env_steps, batch_size)


WORKERS = {"steps": worker_steps, "ppo": worker_ppo}


# ----------------------------------------------------------------------------- figures
#: (figure, numerator, denominators): seconds per env-step of the numerator over the sum of
#: the denominators', per process
STEP_RATIOS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    (f"`gym.make` env step / native per-env step (B = {BATCH}), 1 path", "gym", ("native",)),
    ("bare `SwarmEnv` step (no wrapper) / native per-env step", "bare", ("native",)),
    ("PettingZoo step, N = 100 / native per-env step", "parallel", ("native",)),
    ("PettingZoo step, N = 100 / its five dicts alone", "parallel", ("dicts",)),
    ("PettingZoo step, N = 100 / (native per-env step + five dicts)", "parallel",
     ("native", "dicts")),
    ("PettingZoo step, N = 10 / native per-env step, N = 10", "parallel_10", ("native_10",)),
    ("PettingZoo step, N = 10 / its five dicts alone", "parallel_10", ("dicts_10",)),
    ("PettingZoo step, N = 10 / (native per-env step + five dicts)", "parallel_10",
     ("native_10", "dicts_10")),
    ("`gym.make` env step / native per-env step, 20 paths", "gym_20", ("native_20",)),
)  # fmt: skip


def step_rows(answers: dict[str, list[Any]]) -> list[dict[str, Any]]:
    """The step figures: per figure the median over the new processes of its ratio, and where
    there is a baseline the median old seconds over the median new seconds of its numerator."""
    new = [a["warm"] for a in answers["new"]]
    old = [a["warm"] for a in answers.get("old", [])]
    rows = []
    for figure, num, dens in STEP_RATIOS:
        ratios = [w[num] / sum(w[d] for d in dens) for w in new]
        rows.append({"figure": figure, "value": float(np.median(ratios)), **ab(num, new, old)})
    for wrapper in answers["new"][0]["chain"][:-1]:
        if f"stub_{wrapper}" in new[0]:
            shares = [(w[f"stub_{wrapper}"] - w["stub"]) / w["gym"] for w in new]
            rows.append({"figure": f"{wrapper}'s share of the `gym.make` step", "percent": True,
                         "value": float(np.median(shares))})  # fmt: skip
    colds = [a["cold"] / a["warm_first"] for a in answers["new"]]
    rows.append({"figure": "`gym.make` env, first steps of a fresh process / warm",
                 "value": float(np.median(colds))})  # fmt: skip
    return rows


def ab(name: str, new: Sequence[dict[str, float]], old: Sequence[dict[str, float]]) -> dict:
    """{"old_over_new": median old seconds / median new seconds of `name`} if there is an old."""
    if not old:
        return {}
    return {"old_over_new": float(np.median([o[name] for o in old]) /
                                  np.median([n[name] for n in new]))}  # fmt: skip


def ppo_rows(answers: dict[str, dict[str, list[Any]]]) -> list[dict[str, Any]]:
    """Per vector env: median learn env-steps/s, the env's share of learn (learn rate / the
    rate stepped alone, per process), new / old learn rates where there is a baseline."""
    rows = []
    for vec_env, runs in answers.items():
        learn = float(np.median([r["learn"] for r in runs["new"]]))
        share = float(np.median([r["learn"] / r["alone"] for r in runs["new"]]))
        row = {"vec_env": vec_env, "learn": learn, "env_share": share}
        if runs.get("old"):
            row["new_over_old"] = learn / float(np.median([r["learn"] for r in runs["old"]]))
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------- output
def print_tables(steps: list[dict[str, Any]], ppo: list[dict[str, Any]], baseline: bool) -> None:
    """The step figures, then the PPO figures (Markdown)."""
    header = ["figure (same fresh process)", "ratio"]
    header += ["A/B: old / new seconds of the step"] if baseline else []
    rows = []
    for row in steps:
        percent = round(100 * row["value"], 1) + 0.0  # (+ 0.0: no "-0.0 %")
        value = f"{percent:.1f} %" if row.get("percent") else f"{row['value']:.2f}"
        cells = [row["figure"], value]
        if baseline:
            cells.append(f"{row['old_over_new']:.2f}" if "old_over_new" in row else "")
        rows.append(cells)
    _timing.print_table(header, rows)
    if not ppo:
        return
    header = ["PPO end to end", "swarm env-steps/s of learn (this host)",
              "env's share of learn"]  # fmt: skip
    header += ["A/B: new / old env-steps/s"] if baseline else []
    rows = []
    for row in ppo:
        cells = [row["vec_env"], f"{row['learn']:,.0f}", f"{100 * row['env_share']:.0f} %"]
        if baseline:
            cells.append(f"{row['new_over_old']:.2f}")
        rows.append(cells)
    _timing.print_table(header, rows)
    rates = {row["vec_env"]: row["learn"] for row in ppo}
    if "dummy" in rates and "native" in rates:
        print(f"PPO native / dummy (learn env-steps/s): {rates['native'] / rates['dummy']:.2f}\n")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="1 process, tiny PPO budgets")
    parser.add_argument("--processes", type=int, default=None, help="fresh processes (3)")
    parser.add_argument("--rounds", type=int, default=None, help="interleaved rounds (5)")
    parser.add_argument("--seconds", type=float, default=None, help="seconds a round (0.2)")
    parser.add_argument("--cold-steps", type=int, default=50, help="first steps timed cold")
    parser.add_argument("--skip-ppo", action="store_true", help="the step figures only")
    parser.add_argument("--baseline-python", default=None, help="A/B against this interpreter")
    parser.add_argument("--json", default=None, help="write the figures to this file")
    _timing.add_worker_arguments(parser, WORKERS)
    return parser.parse_args()


def main() -> int:
    args = parse_args()
    if _timing.serve_worker(args, WORKERS):
        return 0
    processes = args.processes or (1 if args.quick else 3)
    per_process = {
        "seconds": args.seconds or (0.02 if args.quick else 0.2),
        "rounds": args.rounds or (2 if args.quick else 5),
        "cold_steps": args.cold_steps,
    }
    pythons = {"new": None, **({"old": args.baseline_python} if args.baseline_python else {})}
    print(f"The env users step against its floor, paper setting, 1 thread, medians of "
          f"{processes} fresh processes ({_timing.compiled_paths()})\n")  # fmt: skip
    steps = _timing.alternate_fresh(__file__, "steps", pythons, processes, **per_process)
    ppo: dict[str, dict[str, list[Any]]] = {}
    for vec_env, n_envs, n_steps, budget, batch in () if args.skip_ppo else PPO_RUNS[args.quick]:
        ppo[vec_env] = _timing.alternate_fresh(
            __file__, "ppo", pythons, processes, vec_env=vec_env, n_envs=n_envs,
            n_steps=n_steps, env_steps=budget, batch_size=batch,
        )  # fmt: skip
    rows, learn = step_rows(steps), ppo_rows(ppo)
    print_tables(rows, learn, bool(args.baseline_python))
    if args.json:
        with open(args.json, "w") as out:
            json.dump({"setting": PAPER, "batch": BATCH, "processes": processes,
                       "baseline_python": args.baseline_python, "steps": rows, "ppo": learn,
                       "raw": {"steps": steps, "ppo": ppo}}, out, indent=1)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
