"""Shared by the throughput benchmarks: settings, steppers, interleaved timing, fresh processes.

Importing this module pins the BLAS pools to one thread (``OPENBLAS_NUM_THREADS`` and the
others) before numpy loads, so a benchmark imports it first; the fresh processes it starts
inherit the setting. It uses public names of `agent_envs` only.

- `SETTINGS`, `env_kwargs`: the paper setting (`agent_envs/Swarm-v0`, N = 100, m = 50,
  20 Brownian paths, eps = 0.05, frozen Jacobian, max_control = 25) and the quick one
  (N = 10, m = 20, 20 paths).
- `single_env_stepper`, `native_stepper`, `bare_stepper`: one env step, one native vector env
  step, one bare `integrator.step` per call (fixed actions, resets inside the timing).
- `plain_kernel_drift`, `inplace_kernel_drift`, `compiled_kernel_drift`: the compute floor of a
  step, the kernel matrix p_kl = w / (alpha^2 + (x_l - x_k)^2) and the drift
  (P x - (P 1) * x) / N for x (paths, N, 1).
- `interleaved`: the median seconds per call of several functions timed in alternating rounds
  (one machine speed for every side of a ratio); `interleaved_for`: the same with each
  function's own number of calls (about the same seconds a round each).
- `CallTimes`, `wrap_compiled`: seconds inside wrapped public functions (the compiled calls).
- `run_fresh`, `serve_worker`: a worker function in a fresh interpreter (cold figures);
  `alternate_fresh`: one worker in several interpreters, fresh processes in turn (A/B runs).
- `print_table`: a Markdown table.
"""

from __future__ import annotations

import os

for _pool in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_pool] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

SETTINGS: dict[str, dict[str, Any]] = {
    "paper": {"n_agents": 100, "n_steps": 50, "n_paths": 20},
    "quick": {"n_agents": 10, "n_steps": 20, "n_paths": 20},
}
COMMON: dict[str, Any] = {"epsilon": 0.05, "jacobian": "frozen", "max_control": 25.0}
#: the Cucker-Smale weight 1 / eps and alpha^2 of the paper setting (the floors' kernel)
WEIGHT, ALPHA2 = 1.0 / 0.05, 0.1**2


def env_kwargs(setting: str, integrator: str, **extra: Any) -> dict[str, Any]:
    """`gym.make` keyword arguments of `setting` ("paper" | "quick") with `integrator`."""
    return {**SETTINGS[setting], **COMMON, "integrator": integrator, **extra}


# ----------------------------------------------------------------------------- steppers
def single_env_stepper(kwargs: dict[str, Any], first_seed: int = 0) -> Callable[[], None]:
    """One `env.step` per call with a fixed action (uniform in [-0.5, 0.5], default_rng(1));
    at an episode's end the env resets with the next seed (inside the timing). The returned
    function has `restart()` (reset with `first_seed` again) and `env` (the unwrapped env)."""
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers the id)
    from agent_envs.envs import ENV_ID

    env = gym.make(ENV_ID, **kwargs).unwrapped
    action = np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape)
    action = action.astype(np.float32)
    state = {"seed": first_seed}
    env.reset(seed=first_seed)

    def step() -> None:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            state["seed"] += 1
            env.reset(seed=state["seed"])

    def restart() -> None:
        state["seed"] = first_seed
        env.reset(seed=first_seed)

    step.restart = restart  # type: ignore[attr-defined]
    step.env = env  # type: ignore[attr-defined]
    return step


def make_native(kwargs: dict[str, Any], num_envs: int) -> Any:
    """The native vector env (`vectorization_mode="vector_entry_point"`) of `num_envs` envs,
    reset with seed 0, unwrapped."""
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers the id)
    from agent_envs.envs import ENV_ID

    env = gym.make_vec(ENV_ID, num_envs, vectorization_mode="vector_entry_point", **kwargs)
    env.reset(seed=0)
    return env.unwrapped


def batch_actions(num_envs: int, n: int) -> np.ndarray:
    """Fixed actions (num_envs, n), uniform in [-0.5, 0.5] (default_rng(1)), float32."""
    return np.random.default_rng(1).uniform(-0.5, 0.5, (num_envs, n)).astype(np.float32)


def native_stepper(kwargs: dict[str, Any], num_envs: int) -> Callable[[], None]:
    """One step of a native vector env of `num_envs` envs per call (fixed actions; the env
    autoresets its envs at their episodes' ends). `.env` is the env."""
    env = make_native(kwargs, num_envs)
    actions = batch_actions(num_envs, kwargs["n_agents"])

    def step() -> None:
        env.step(actions)

    step.env = env  # type: ignore[attr-defined]
    return step


def bare_stepper(integrator: str, n_paths: int, n: int = 100, m: int = 50) -> Callable[[], None]:
    """One `integrator.step` per call (zero control, `SwarmModel` with eps = 0.05), episodes
    of m steps from uniform starts drawn from default_rng(k) for episode k; x (n_paths, n, 1)."""
    from agent_envs import SwarmModel, SwarmParams, make_integrator
    from agent_envs.draws import brownian_increments, uniform_positions

    model = SwarmModel(SwarmParams(n_agents=n, epsilon=0.05))
    scheme = make_integrator(integrator)
    dt, control = 1.0 / m, np.zeros((n, 1))
    state: dict[str, Any] = {"episode": -1, "n": m}

    def step() -> None:
        if state["n"] == m:
            state["episode"] += 1
            state["rng"] = np.random.default_rng(state["episode"])
            x0 = uniform_positions(state["rng"], n, 1)
            state["x"], state["n"] = np.broadcast_to(x0, (n_paths, n, 1)).copy(), 0
        dw = brownian_increments(state["rng"], state["x"].shape, dt)
        state["x"] = scheme.step(model, state["x"], control, state["n"] * dt, dt, dw)
        state["n"] += 1

    return step


# ----------------------------------------------------------------------------- floors
def _positions(n_paths: int, n: int) -> np.ndarray:
    return np.random.default_rng(0).uniform(-1.0, 1.0, (n_paths, n, 1))


def plain_kernel_drift(n_paths: int = 20, n: int = 100) -> Callable[[], None]:
    """Kernel matrix and drift as numpy written without this project (temporaries and all):
    ``p = w / (alpha^2 + (x_l - x_k)^2); (p @ x - p.sum(-1) * x) / N``."""
    x = _positions(n_paths, n)

    def step() -> None:
        p = WEIGHT / (ALPHA2 + (x[..., None, :, 0] - x[..., :, None, 0]) ** 2)
        (p @ x - p.sum(axis=-1)[..., None] * x) / n

    return step


def inplace_kernel_drift(n_paths: int = 20, n: int = 100) -> Callable[[], None]:
    """The same in preallocated buffers (np.subtract/multiply/add/divide with out=, one matmul
    P [x | 1]): the fewest numpy passes for P and the drift, no allocation of size N^2."""
    x = _positions(n_paths, n)
    p = np.empty((n_paths, n, n))
    augmented = np.ones((n_paths, n, 2))
    product = np.empty((n_paths, n, 2))

    def step() -> None:
        np.subtract(x[..., None, :, 0], x[..., :, None, 0], out=p)
        np.multiply(p, p, out=p)
        np.add(p, ALPHA2, out=p)
        np.divide(WEIGHT, p, out=p)
        augmented[..., :1] = x
        np.matmul(p, augmented, out=product)
        (product[..., :1] - product[..., 1:] * x) / n

    return step


def compiled_kernel_drift(n_paths: int = 20, n: int = 100) -> Callable[[], None] | None:
    """The same by the env's compiled kernel pass (`laplacian.compiled_cucker_smale_drift`,
    P's lower triangle, s = P 1 and L(x) x), or None where it does not serve (no numba,
    ``AGENT_ENVS_NUMBA=0``, or ``native.use("kernel", False)``)."""
    from agent_envs.dynamics import laplacian

    if not laplacian.load_compiled_kernel():
        return None
    x = _positions(n_paths, n)
    p = np.empty((n_paths, n, n))
    return lambda: laplacian.compiled_cucker_smale_drift(x, WEIGHT, ALPHA2, p)  # type: ignore[return-value]


def kernel_drift_floor(n_paths: int, n: int = 100) -> Callable[[], None]:
    """The env's own kernel pass: the compiled one where it serves, else in-place numpy."""
    return compiled_kernel_drift(n_paths, n) or inplace_kernel_drift(n_paths, n)


# ----------------------------------------------------------------------------- timing
def interleaved(fns: dict[str, Callable[[], Any]], calls: int, rounds: int) -> dict[str, float]:
    """Median over `rounds` interleaved rounds of the seconds per call of each function (each
    called once first, untimed)."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            start = time.perf_counter()
            for _ in range(calls):
                fn()
            times[name].append((time.perf_counter() - start) / calls)
    return {name: float(np.median(t)) for name, t in times.items()}


def interleaved_for(
    fns: dict[str, Callable[[], Any]], seconds: float, rounds: int
) -> dict[str, float]:
    """Median over `rounds` interleaved rounds of the seconds per call of each function, each
    called `calls_for(fn, seconds)` times a round (so a slow and a fast function both take
    about `seconds` a round; the two calls that size it come first, untimed)."""
    calls = {name: calls_for(fn, seconds, least=1) for name, fn in fns.items()}
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            start = time.perf_counter()
            for _ in range(calls[name]):
                fn()
            times[name].append((time.perf_counter() - start) / calls[name])
    return {name: float(np.median(t)) for name, t in times.items()}


def calls_for(fn: Callable[[], Any], seconds: float, least: int = 2) -> int:
    """How many calls of `fn` take about `seconds` (from one timed call after a warm-up)."""
    fn()
    start = time.perf_counter()
    fn()
    return max(least, int(seconds / max(time.perf_counter() - start, 1e-9)))


class CallTimes:
    """Inclusive seconds per wrapped call, the compiled calls' seconds also charged to the
    innermost wrapped call they ran in (``compiled in <key>``): a stack of the open calls."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.stack: list[str] = []
        self.undo: list[tuple[Any, str, Any]] = []
        self.keys: list[str] = []

    def wrap(self, owner: Any, name: str, key: str, compiled: bool = False) -> None:
        """Time `owner.name` (a public function or method) under `key` until `restore`;
        AttributeError where `owner` has no such name (a renamed function would otherwise drop
        its row from the table without a word)."""
        fn = getattr(owner, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            self.stack.append(key)
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.perf_counter() - start
                self.stack.pop()
                self.seconds[key] = self.seconds.get(key, 0.0) + spent
                if compiled and self.stack:
                    inner = f"compiled in {self.stack[-1]}"
                    self.seconds[inner] = self.seconds.get(inner, 0.0) + spent

        self.undo.append((owner, name, fn))
        if key not in self.keys:
            self.keys.append(key)
        setattr(owner, name, timed)

    def restore(self) -> None:
        """Put every wrapped function back."""
        for owner, name, fn in reversed(self.undo):
            setattr(owner, name, fn)
        self.undo.clear()


#: the public entry points of the compiled modules that a step calls, by path
COMPILED_CALLS = {
    "kernel": ("cucker_smale_drift", "cucker_smale_drift_threads"),
    "lanczos": ("frozen_advance", "frozen_advance_threads", "frozen_lanczos"),
    "step": ("prologue", "epilogue"),
}


def wrap_compiled(times: CallTimes) -> None:
    """Time the compiled calls (`agent_envs.native`'s kernel pass, Lanczos, fused step and the
    native env's prologue and epilogue) under the key "compiled"; none where numba is off."""
    from agent_envs import native

    for name, functions in COMPILED_CALLS.items():
        if native.available(name):
            for function in functions:
                times.wrap(native.loaded(name), function, "compiled", compiled=True)


def compiled_share(step: Callable[[], None], calls: int, rounds: int) -> dict[str, float]:
    """Seconds per call of `step` ("total") and the part inside the compiled calls
    ("compiled"), medians over `rounds` rounds of `calls` calls; empty without numba."""
    times = CallTimes()
    wrap_compiled(times)
    if not times.keys:
        return {}
    found: dict[str, list[float]] = {"total": [], "compiled": []}
    try:
        step()
        for _ in range(rounds):
            times.seconds = {}
            start = time.perf_counter()
            for _ in range(calls):
                step()
            found["total"].append((time.perf_counter() - start) / calls)
            found["compiled"].append(times.seconds.get("compiled", 0.0) / calls)
    finally:
        times.restore()
    return {key: float(np.median(values)) for key, values in found.items()}


# ----------------------------------------------------------------------------- processes
def run_fresh(script: str, worker: str, python: str | None = None, **kwargs: Any) -> Any:
    """Run `worker` of benchmark `script` (its path) in a fresh process of `python` (this
    interpreter by default) and return its JSON answer (the last line of its stdout)."""
    cmd = [python or sys.executable, os.path.abspath(script), "--worker", worker]
    cmd += ["--worker-args", json.dumps(kwargs)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"worker {worker} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def alternate_fresh(
    script: str, worker: str, pythons: dict[str, str | None], processes: int, **kwargs: Any
) -> dict[str, list[Any]]:
    """`processes` rounds of `worker` in a fresh process of each interpreter of `pythons`
    (label -> path, None for this one), in turn within a round (the sides of an A/B share the
    machine's load): label -> the answers, in round order."""
    answers: dict[str, list[Any]] = {label: [] for label in pythons}
    for _ in range(processes):
        for label, python in pythons.items():
            answers[label].append(run_fresh(script, worker, python, **kwargs))
    return answers


def add_worker_arguments(parser: argparse.ArgumentParser, workers: Sequence[str]) -> None:
    """The hidden `--worker NAME --worker-args JSON` options `run_fresh` calls a script with."""
    parser.add_argument("--worker", choices=list(workers), help=argparse.SUPPRESS)
    parser.add_argument("--worker-args", default="{}", help=argparse.SUPPRESS)


def serve_worker(args: argparse.Namespace, workers: dict[str, Callable[..., Any]]) -> bool:
    """In a worker process (`--worker`): run it, print its JSON answer, return True."""
    if not args.worker:
        return False
    print(json.dumps(workers[args.worker](**json.loads(args.worker_args))))
    return True


# ----------------------------------------------------------------------------- output
def print_table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    """A Markdown table, then a blank line."""
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(str(cell) for cell in row) + " |")
    print()


def compiled_paths() -> str:
    """Which compiled paths serve here (`agent_envs.native.status()`), one line."""
    from agent_envs import native

    serving = [name for name, on in native.status().items() if on]
    return "compiled paths: " + (", ".join(serving) if serving else "none (numpy)")
