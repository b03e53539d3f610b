"""Throughput at the paper's setting: env steps cold and warm, the native vector env, PPO.

Settings (`agent_envs/Swarm-v0`, frozen Jacobian, max_control = 25, eps = 0.05):
paper = N 100, m 50, 20 Brownian paths; quick = N 10, m 20, 20 paths.

1. Env steps/s, SERB and EM. **cold**: the first 100 steps of a fresh subprocess (env made and
   reset first; resets with seed 0, 1, ... at each episode end, inside the timing); **warm**: the
   same 100 steps (same seeds) again in that process, median of `--rounds` rounds; cold/warm is
   their ratio. Each figure is the median over `--rounds` fresh processes (100 quick steps take
   ~10 ms, so one preemption moves a single process's ratio by 10-40 %).
2. Ratios in one process (interleaved rounds, medians): the warm SERB env step over the EM env
   step (paper); the EM env step over a plain numpy kernel + drift of the same size
   (``p = w / (alpha^2 + (x_l - x_k)^2); (p @ x - p.sum(-1) * x) / N``, its floor), over the
   same in place, and over the env's own kernel pass (compiled with numba); one bare
   SERB step over one bare EM step (`integrator.step` with a `SwarmModel`, N = 100, 1 path,
   zero control, the same states: episodes from uniform starts); SERB / EM where interpreter
   time does not dilute it: a native vector env of 16 paper envs (20 paths each,
   compute-bound) and the compiled calls alone.
2b. Krylov dimensions per member and step of the paper SERB env, this tree only
   (`_oracle_dimension`: the smallest dimension within rtol of the dense eigh value, which no
   stopping rule can beat), one compiled product in cache and a near-consensus step's compiled
   phi-action per member, and the products-only floors of SERB / EM they give.
3. Native vector env (`gym.make_vec(..., vectorization_mode="vector_entry_point")`) at
   B = 1, 16, 64 for 1 and 20 paths against B single envs stepped in a loop, and against
   Gymnasium's SyncVectorEnv at B = 64, 1 path (env-steps/s, interleaved rounds of about 0.3 s
   of the slower side each, medians). The last column is the time of the unavoidable compute
   (one kernel matrix and drift per system, B x P systems, by the env's own pass: the compiled
   one with numba, else in-place numpy) as a share of the native step: near 100 % the env is
   compute-bound.
4. PPO (SB3) on `agent_envs.training.native_vec_env.NativeVecEnv` at the paper setting with the
   training layer's hyperparameters (`HYPERPARAMS["ppo"]`, VecNormalize, horizon as
   termination; torch on one thread), `--ppo-timesteps` timesteps in a fresh process: env-steps/s
   of `model.learn` and the share of its wall time spent inside the env's reset/step_wait.

5. `--device cuda` (or any torch device): the native vector env there at B = `--device-envs`
   (4096), paper and quick settings, SERB and EM, 1 and 20 paths, each in a fresh process:
   warm env-steps/s, cold/warm over the first `--device-steps` steps, the shares of the host's
   Brownian draws and of the integrator's batched step, the device memory peak; against the
   numpy native env on this host's CPU at B <= `--device-cpu-envs` (this tree only).

6. Where a step's time goes, call by call (this tree only): `time.perf_counter` around the
   env step's calls (the compiled calls charged to the call they ran in), the paper single env
   with SERB and with EM (20 episodes each, alternating) and the native vector env at B = 64,
   1 path; SERB's compiled call at an episode's first three steps against later ones.

`--baseline-python PATH` runs parts 1, 3 and 4 (and 2) again with another interpreter, e.g. a
virtual environment with an older checkout of the project installed, and prints both (the
"before" column): the workers only use public APIs that existed before the workspaces. For the
compiled Lanczos, PATH may be a two-line script that runs this interpreter with the compiled
path switched off (`AGENT_ENVS_NUMBA=0 exec .venv/bin/python "$@"`): the numpy Lanczos.

Part 1's last column is the fresh process's one-time cost before its first step (import the
package, make the env, reset it): with numba installed it includes importing numba and loading
the compiled Lanczos from numba's cache (compiling it instead, a few seconds, the first time
in a cache directory). It is not in the cold steps.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_throughput.py [--baseline-python PY]
    python benchmarks/bench_throughput.py --device cuda --skip cold ratios krylov vector ppo

The BLAS pools are set to one thread below, before numpy loads (the workers inherit it). On a
shared machine absolute figures move with the load: compare the ratios, each measured within
one process (parts 2-3) or on the same steps (part 1).
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
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

SETTINGS: dict[str, dict[str, Any]] = {
    "paper": {"n_agents": 100, "n_steps": 50, "n_paths": 20},
    "quick": {"n_agents": 10, "n_steps": 20, "n_paths": 20},
}
COMMON = {"epsilon": 0.05, "jacobian": "frozen", "max_control": 25.0}
COLD_STEPS = 100


def env_kwargs(setting: str, integrator: str, **extra: Any) -> dict[str, Any]:
    return {**SETTINGS[setting], **COMMON, "integrator": integrator, **extra}


# ----------------------------------------------------------------------------- workers
def single_env_stepper(kwargs: dict[str, Any], first_seed: int = 0) -> Callable[[], None]:
    """One `env.step` per call, with a fixed action; resets with the next seed at episode end."""
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
    return step


def worker_cold(setting: str, integrator: str, rounds: int) -> dict[str, float]:
    """Seconds per step of the first COLD_STEPS steps of this process, then warm (median);
    and the seconds to import the package, make the env and reset it in this fresh process
    (where the compiled Lanczos is loaded, when numba is installed)."""
    start = time.perf_counter()
    step = single_env_stepper(env_kwargs(setting, integrator))
    setup = time.perf_counter() - start

    def block() -> float:
        start = time.perf_counter()
        for _ in range(COLD_STEPS):
            step()
        return (time.perf_counter() - start) / COLD_STEPS

    cold = block()
    warm = []
    for _ in range(rounds):
        step.restart()  # type: ignore[attr-defined]
        warm.append(block())
    return {"cold": cold, "warm": float(np.median(warm)), "setup": setup}


def interleaved(fns: dict[str, Callable[[], None]], calls: int, rounds: int) -> dict[str, float]:
    """Median over `rounds` interleaved rounds of the seconds per call of each function."""
    for fn in fns.values():
        fn()  # warm-up
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            start = time.perf_counter()
            for _ in range(calls):
                fn()
            times[name].append((time.perf_counter() - start) / calls)
    return {name: float(np.median(t)) for name, t in times.items()}


def bare_stepper(integrator: str, n_paths: int) -> Callable[[], None]:
    """One `integrator.step` per call at N = 100 (zero control), episodes of m = 50 steps from
    uniform starts drawn from default_rng(k) for episode k."""
    from agent_envs import SwarmModel, SwarmParams, make_integrator
    from agent_envs.simulator import brownian_increments, uniform_positions

    n, m = 100, 50
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


def plain_kernel_drift(n_paths: int = 20, n: int = 100) -> Callable[[], None]:
    """The floor of an env step: numpy kernel matrix + drift for x (n_paths, n, 1), as written
    without this project (temporaries and all)."""
    x = np.random.default_rng(0).uniform(-1.0, 1.0, (n_paths, n, 1))
    w, alpha2 = 1.0 / 0.05, 0.1**2

    def step() -> None:
        p = w / (alpha2 + (x[..., None, :, 0] - x[..., :, None, 0]) ** 2)
        (p @ x - p.sum(axis=-1)[..., None] * x) / n

    return step


def inplace_kernel_drift(n_paths: int = 20, n: int = 100) -> Callable[[], None]:
    """The same in preallocated buffers (np.subtract/multiply/add/divide with out=, one matmul
    P [x | 1]): the fewest numpy passes for P and the drift, no allocation of size N^2."""
    x = np.random.default_rng(0).uniform(-1.0, 1.0, (n_paths, n, 1))
    w, alpha2 = 1.0 / 0.05, 0.1**2
    p = np.empty((n_paths, n, n))
    augmented = np.ones((n_paths, n, 2))
    product = np.empty((n_paths, n, 2))

    def step() -> None:
        np.subtract(x[..., None, :, 0], x[..., :, None, 0], out=p)
        np.multiply(p, p, out=p)
        np.add(p, alpha2, out=p)
        np.divide(w, p, out=p)
        augmented[..., :1] = x
        np.matmul(p, augmented, out=product)
        (product[..., :1] - product[..., 1:] * x) / n

    return step


#: where the numba modules of `agent_envs.native` were in trees before it (the workers also
#: run older checkouts: `--baseline-python`)
_MODULES_BEFORE_NATIVE = {
    "kernel": "agent_envs.dynamics.compiled_kernel",
    "lanczos": "agent_envs.integrators.compiled_lanczos",
}


def compiled_module(name: str) -> Any:
    """The numba module `agent_envs.native.<name>` ("kernel" or "lanczos"), or, in a tree
    before the native layer, the module that held it (importing it imports numba)."""
    import importlib

    try:
        importlib.import_module("agent_envs.native")
    except ImportError:
        return importlib.import_module(_MODULES_BEFORE_NATIVE[name])
    return importlib.import_module(f"agent_envs.native.{name}")


def compiled_kernel_drift(n_paths: int = 20, n: int = 100) -> Callable[[], None] | None:
    """The same by the compiled kernel pass (`agent_envs.native.kernel`, what the env
    runs with numba installed), or None where the tree has none (an older checkout) or numba is
    off."""
    try:
        from agent_envs.dynamics import laplacian

        if not laplacian.load_compiled_kernel():
            return None
    except (ImportError, AttributeError):
        return None
    x = np.random.default_rng(0).uniform(-1.0, 1.0, (n_paths, n, 1))
    p = np.empty((n_paths, n, n))
    return lambda: laplacian.compiled_cucker_smale_drift(x, 1.0 / 0.05, 0.1**2, p)


def kernel_drift_floor(n_paths: int) -> Callable[[], None]:
    """The compiled kernel pass where there is one, else the in-place numpy passes."""
    return compiled_kernel_drift(n_paths) or inplace_kernel_drift(n_paths)


def matrix_pass(n_paths: int = 20, n: int = 100) -> Callable[[], None]:
    """One Lanczos dimension's products at the paper setting, as the env's step takes them:
    the compiled symmetric product (`lower_product`, P's lower triangle) of each of the
    `n_paths` members' P, on a cache-line-aligned workspace (`aligned_empty`), the members in
    one compiled loop; where numba is missing or switched off, or those functions are (trees
    before them), one numpy product rows (n_paths, 1, n) @ P (n_paths, n, n), as the steps."""
    p_full = np.random.default_rng(0).uniform(size=(n_paths, n, n))
    try:
        from numba import njit

        from agent_envs.arrays import aligned_empty
        from agent_envs.dynamics.laplacian import load_compiled_kernel

        compiled = load_compiled_kernel()  # (False with AGENT_ENVS_NUMBA=0: numpy's steps)
        lower_product = compiled_module("kernel").lower_product if compiled else None
    except (ImportError, AttributeError):
        compiled = False
    if not compiled:
        rows = np.ones((n_paths, 1, n))
        return lambda: rows @ p_full

    @njit
    def over_members(p: Any, q: Any, w: Any, n: int) -> None:
        for b in range(p.shape[0]):
            lower_product(p[b], q[b], w[b], n)

    p = aligned_empty((n_paths, n, n))
    p[...] = p_full
    q, w = np.ones((n_paths, n)), np.empty((n_paths, n))
    over_members(p, q, w, n)  # (compiled here, not in the timed rounds)
    return lambda: over_members(p, q, w, n)


class _CallTimes:
    """Inclusive seconds per wrapped call, and the compiled calls' seconds charged to the
    innermost wrapped call they ran in (`compiled in <key>`): a stack of the open calls."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.stack: list[str] = []
        self.undo: list[tuple[Any, str, Any]] = []
        self.keys: list[str] = []  # (of the calls wrapped, in order)

    def wrap(self, owner: Any, name: str, key: str, compiled: bool = False) -> None:
        fn = getattr(owner, name, None)
        if fn is None:
            return

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
        for owner, name, fn in reversed(self.undo):
            setattr(owner, name, fn)
        self.undo.clear()


def _wrap_compiled(times: _CallTimes) -> None:
    """Time the compiled calls under the key "compiled": the kernel pass, the compiled Lanczos,
    the fused step and the native env's prologue and epilogue (what numba runs); nothing in a
    tree without them (numba missing or switched off, or a tree before them: the workers also
    run older checkouts)."""
    try:  # the native layer: every compiled module through its one loader
        from agent_envs import native
    except ImportError:
        native = None
    if native is not None:
        for name, functions in (
            ("kernel", ("cucker_smale_drift",)),
            ("lanczos", ("frozen_advance", "frozen_lanczos")),
            ("step", ("prologue", "epilogue")),
        ):
            if native.available(name):
                for function in functions:
                    times.wrap(native.loaded(name), function, "compiled", compiled=True)
        return
    # trees before the native layer
    try:  # (trees before the workspaces have no laplacian module: nothing compiled)
        from agent_envs.dynamics import laplacian
        from agent_envs.integrators import phi_functions
    except ImportError:
        return
    if getattr(laplacian, "load_compiled_kernel", lambda: False)():
        times.wrap(laplacian._compiled_kernel, "cucker_smale_drift", "compiled", compiled=True)
    if getattr(phi_functions, "load_compiled", lambda: False)():
        for name in ("frozen_advance", "frozen_lanczos"):
            times.wrap(phi_functions._compiled, name, "compiled", compiled=True)
    try:  # the native env's compiled prologue and epilogue (trees before them: none)
        from agent_envs.envs import fast_step
    except ImportError:
        return
    if fast_step.load_compiled_step():
        for name in ("prologue", "epilogue"):
            times.wrap(fast_step.compiled_step(), name, "compiled", compiled=True)


def compiled_share(
    step: Callable[[], None], calls: int, rounds: int, draws: bool = False
) -> dict[str, float]:
    """Seconds per call of `step` and the part of them spent inside the compiled calls (the
    kernel pass, the compiled Lanczos and the fused step: what numba runs), medians over
    `rounds` rounds of `calls` calls: the step's compute, as against its interpreter share.
    With `draws`, also the part inside the native vector env's Brownian draws (each env's own
    generator, `fill_brownian_increments`). Empty where the tree has no compiled calls (numba
    missing, or a tree before them)."""
    times = _CallTimes()
    _wrap_compiled(times)
    if not times.keys:
        return {}
    if draws:
        from agent_envs.envs import vector_env

        times.wrap(vector_env, "fill_brownian_increments", "draws")
    found: dict[str, list[float]] = {"total": [], **{key: [] for key in times.keys}}
    try:
        step()
        for _ in range(rounds):
            times.seconds = {}
            start = time.perf_counter()
            for _ in range(calls):
                step()
            found["total"].append((time.perf_counter() - start) / calls)
            for key in times.keys:
                found[key].append(times.seconds.get(key, 0.0) / calls)
    finally:
        times.restore()
    return {key: float(np.median(values)) for key, values in found.items()}


def krylov_products_per_step(step: Callable[[], None], steps: int = 100) -> float:
    """Mean number of Lanczos matrix products per call of `step` over `steps` calls, counted on
    the phi-function module's operator wrapper (the numpy Lanczos: the compiled one, which
    stops at the same dimensions, is switched off while counting)."""
    from agent_envs.integrators import phi_functions

    count = [0]
    original = phi_functions._RowOperator.apply
    switch = getattr(phi_functions, "use_compiled", None)
    compiled_before = switch(False) if switch else False

    def counted(self: Any, rows: Any) -> Any:
        count[0] += 1
        return original(self, rows)

    phi_functions._RowOperator.apply = counted
    try:
        for _ in range(steps):
            step()
    finally:
        phi_functions._RowOperator.apply = original
        if switch:
            switch(compiled_before)
    return count[0] / steps


def native_stepper(kwargs: dict[str, Any], num_envs: int) -> Callable[[], None]:
    """One step of a native vector env of `num_envs` envs per call (fixed actions; the env
    autoresets its envs at their episodes' ends)."""
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers the id)
    from agent_envs.envs import ENV_ID

    env = gym.make_vec(ENV_ID, num_envs, vectorization_mode="vector_entry_point", **kwargs)
    env.reset(seed=0)
    n = kwargs["n_agents"]
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, (num_envs, n)).astype(np.float32)
    return lambda: env.step(actions)  # type: ignore[no-any-return]


def worker_ratios(rounds: int) -> dict[str, float]:
    fns = {
        "serb_env": single_env_stepper(env_kwargs("paper", "serb")),
        "em_env": single_env_stepper(env_kwargs("paper", "em")),
        # compute-bound: 16 envs of 20 paths in one native env (320 systems per step)
        "serb_native": native_stepper(env_kwargs("paper", "serb"), 16),
        "em_native": native_stepper(env_kwargs("paper", "em"), 16),
        "plain": plain_kernel_drift(),
        "inplace": inplace_kernel_drift(),
        "floor": kernel_drift_floor(20),
        "matrix_pass": matrix_pass(),
        "serb_bare_1": bare_stepper("serb", 1),
        "em_bare_1": bare_stepper("em", 1),
    }
    out = interleaved(fns, 100, rounds)
    # the same steps as part 1 (paper env) and as the bare 1-path timing (its first 100 steps)
    out["krylov_products"] = krylov_products_per_step(
        single_env_stepper(env_kwargs("paper", "serb"))
    )
    out["krylov_products_1"] = krylov_products_per_step(bare_stepper("serb", 1))
    # the compiled share of each env step, SERB and EM in alternating rounds (the envs above)
    steppers = {"serb": fns["serb_env"], "em": fns["em_env"]}
    shares: dict[str, list[dict[str, float]]] = {k: [] for k in steppers}
    for _ in range(rounds):
        for k, stepper in steppers.items():
            shares[k].append(compiled_share(stepper, 100, 1))
    for k, found in shares.items():
        if found[0]:
            for key in ("total", "compiled"):
                out[f"{k}_{key}"] = float(np.median([f[key] for f in found]))
    return out


def worker_vector(batches: list[int], paths: list[int], rounds: int) -> dict[str, float]:
    """env-steps/s of the native vector env and of B single envs in a loop (and Sync)."""
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.envs import ENV_ID

    out: dict[str, float] = {}
    for n_paths in paths:
        for b in batches:
            kwargs = env_kwargs("paper", "serb", n_paths=n_paths)
            native = gym.make_vec(
                ENV_ID, num_envs=b, vectorization_mode="vector_entry_point", **kwargs
            )
            native.reset(seed=0)
            actions = np.random.default_rng(1).uniform(-0.5, 0.5, (b, 100)).astype(np.float32)
            singles = [single_env_stepper(kwargs, first_seed=1000 * i) for i in range(b)]
            fns = {
                "native": lambda native=native, actions=actions: native.step(actions),
                "loop": lambda singles=singles: [s() for s in singles],
            }
            # the compute floor: one kernel matrix + drift per system and step (in-place numpy,
            # in chunks of at most 100 systems = 8 MB, as the native env's blocks)
            systems = b * n_paths
            chunk = min(systems, 100)
            floor = kernel_drift_floor(chunk)
            fns["floor"] = lambda floor=floor, reps=systems / chunk: [
                floor() for _ in range(max(1, round(reps)))
            ]
            if n_paths == 1 and b == max(batches):
                sync = gym.make_vec(ENV_ID, num_envs=b, vectorization_mode="sync", **kwargs)
                sync.reset(seed=0)
                fns["sync"] = lambda sync=sync, actions=actions: sync.step(actions)
                plan = getattr(native.unwrapped, "plan", None)  # (older trees: none)
                if plan is not None and plan.compiled_step:
                    # the same env made with its compiled prologue and epilogue off: the numpy
                    # step (its plan's envelope)
                    from agent_envs import native as agent_native

                    before = agent_native.use("step", False)
                    try:
                        plain = gym.make_vec(
                            ENV_ID, num_envs=b, vectorization_mode="vector_entry_point", **kwargs
                        )
                    finally:
                        agent_native.use("step", before)
                    assert plain.unwrapped.plan.envelope == "numpy"
                    plain.reset(seed=0)
                    fns["numpy_step"] = lambda plain=plain, actions=actions: plain.step(actions)
            # blocks of about 0.3 s of the slower side, from one timed call of each after a
            # warm-up (two calls per block at 20 paths, as before, moved the ratio by 0.1)
            probe = {}
            for name in ("native", "loop"):
                fns[name]()
                start = time.perf_counter()
                fns[name]()
                probe[name] = time.perf_counter() - start
            calls = max(2, int(0.3 / max(probe.values())))
            t = interleaved(fns, calls, rounds)
            for name, seconds in t.items():
                out[f"{name}/B{b}/P{n_paths}"] = b / seconds
            if "sync" in fns:
                # the native step's compiled part and draws, and Sync's step, per env-step, in
                # alternating rounds (one machine speed for the bound's two sides)
                shares: dict[str, list[dict[str, float]]] = {"native": [], "sync": []}
                for _ in range(rounds):
                    for name in shares:
                        shares[name].append(compiled_share(fns[name], calls, 1, draws=True))
                if shares["native"][0]:
                    for name, found in shares.items():
                        for key in found[0]:
                            value = float(np.median([f[key] for f in found])) / b
                            out[f"{name}_{key}/B{b}/P{n_paths}"] = value
    return out


def worker_threads(rounds: int) -> dict[str, float]:
    """env-steps/s of the native vector env on 1 thread and on every thread numba allows
    (`num_threads`), against SyncVectorEnv (B = 64, 1 path) and B single envs in a loop (B = 16,
    20 paths), interleaved in one process; SERB, and EM at B = 64, 1 path."""
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.dynamics.laplacian import max_compiled_threads
    from agent_envs.envs import ENV_ID

    most = max_compiled_threads()
    out: dict[str, float] = {"threads": float(most)}
    for integrator, b, n_paths in (("serb", 64, 1), ("serb", 16, 20), ("em", 64, 1)):
        kwargs = env_kwargs("paper", integrator, n_paths=n_paths)
        actions = np.random.default_rng(1).uniform(-0.5, 0.5, (b, 100)).astype(np.float32)
        fns: dict[str, Callable[[], None]] = {}
        for threads in sorted({1, most}):
            fns[f"native{threads}"] = native_stepper({**kwargs, "num_threads": threads}, b)
        if n_paths == 1:
            sync = gym.make_vec(ENV_ID, num_envs=b, vectorization_mode="sync", **kwargs)
            sync.reset(seed=0)
            fns["baseline"] = lambda sync=sync, a=actions: sync.step(a)
        else:
            singles = [single_env_stepper(kwargs, first_seed=1000 * i) for i in range(b)]
            fns["baseline"] = lambda singles=singles: [s() for s in singles]
        fns["baseline"]()
        start = time.perf_counter()
        fns["baseline"]()
        calls = max(2, int(0.3 / (time.perf_counter() - start)))
        for name, seconds in interleaved(fns, calls, rounds).items():
            out[f"{name}/{integrator}/B{b}/P{n_paths}"] = b / seconds
    # the paper single env (20 paths), SERB and EM, on 1 thread and on `most`
    singles = {}
    for threads in sorted({1, most}):
        for integrator in ("serb", "em"):
            singles[f"single{threads}/{integrator}"] = single_env_stepper(
                env_kwargs("paper", integrator, num_threads=threads)
            )
    for name, seconds in interleaved(singles, 100, rounds).items():
        out[name] = 1.0 / seconds
    return out


def worker_ppo(timesteps: int, threads: int = 1) -> dict[str, float]:
    """PPO env-steps/s at the paper setting (fresh process), and the env's share of the time;
    the native env on `threads` threads (`num_threads`; trees before it: 1 only)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from agent_envs.training.config import GYM_ENV_ID, TrainConfig, resolve_hyperparams
    from agent_envs.training.learners.native_vec_env import NativeVecEnv

    try:  # the presets' module (its name before the presets were shared: sweep_grid)
        from agent_envs.training.commands.presets import PAPER_ENV
    except ImportError:
        from agent_envs.training.sweep_grid import PAPER_ENV

    torch.set_num_threads(1)
    config = TrainConfig(env_id=GYM_ENV_ID, vec_env="native", seed=0, env_kwargs=dict(PAPER_ENV))
    kwargs, n_envs, normalize_kwargs, policy = resolve_hyperparams(config)
    extra = {"num_threads": threads} if threads > 1 else {}
    venv = NativeVecEnv(n_envs, dict(PAPER_ENV), horizon_as_termination=True, **extra)
    venv.seed(0)
    in_env = [0.0]
    for name in ("step_wait", "reset"):
        method = getattr(venv, name)

        def timed(*args: Any, _method: Callable[..., Any] = method) -> Any:
            start = time.perf_counter()
            try:
                return _method(*args)
            finally:
                in_env[0] += time.perf_counter() - start

        setattr(venv, name, timed)
    normalized = VecNormalize(venv, **(normalize_kwargs or {}))
    model = PPO(policy, normalized, seed=0, device="cpu", **kwargs)
    start = time.perf_counter()
    model.learn(total_timesteps=timesteps)
    elapsed = time.perf_counter() - start
    return {
        "steps_per_s": model.num_timesteps / elapsed,
        "env_share": in_env[0] / elapsed,
        "n_envs": float(n_envs),
        "timesteps": float(model.num_timesteps),
    }


def _oracle_dimension(a: np.ndarray, v: np.ndarray, order: int, rtol: float, deflate: bool) -> int:
    """The smallest Krylov dimension m whose Lanczos approximation of phi_order(A) v is within
    rtol of the dense eigh value (relative, 2-norm); A (n, n) symmetric, v (n,). With `deflate`
    the constant vector is taken out first, as the library does when it knows A 1 = 0."""
    return _oracle_lanczos(a, v, order, rtol, deflate)[0]


def _oracle_lanczos(
    a: np.ndarray, v: np.ndarray, order: int, rtol: float, deflate: bool
) -> tuple[int, np.ndarray, np.ndarray]:
    """(m, the diagonal (m,) and off-diagonal (m - 1,) of T_m) at `_oracle_dimension`'s m."""
    from math import factorial

    from agent_envs.integrators.phi_functions import phi_scalar

    lam, z = np.linalg.eigh(a)
    exact = z @ (phi_scalar(lam, order) * (z.T @ v))
    mean = float(v.mean()) if deflate else 0.0
    rest = v - mean
    beta0 = np.linalg.norm(rest)
    if beta0 == 0.0:
        return 1, np.zeros(1), np.zeros(0)
    basis, alphas, betas = [rest / beta0], [], []
    for m in range(1, a.shape[0] + 1):
        w = a @ basis[-1]
        alphas.append(w @ basis[-1])
        w = w - alphas[-1] * basis[-1]
        if m > 1:
            w = w - (w @ basis[-2]) * basis[-2]
        t = np.diag(alphas) + np.diag(betas, 1) + np.diag(betas, -1)
        tl, tz = np.linalg.eigh(t)
        approx = beta0 * np.array(basis).T @ (tz @ (phi_scalar(tl, order) * tz[0]))
        approx = approx + mean / factorial(order)
        if np.linalg.norm(approx - exact) <= rtol * np.linalg.norm(exact):
            return m, np.array(alphas), np.array(betas)
        betas.append(np.linalg.norm(w))
        basis.append(w / betas[-1])
    return a.shape[0], np.array(alphas), np.array(betas[: len(alphas) - 1])


def worker_krylov(episodes: int = 2, members: int = 4) -> dict[str, float]:
    """Krylov dimensions per member and step of the paper SERB env: reached by the library's
    Lanczos (its numpy reference: the compiled one stops at the same dimensions) and the oracle
    (`_oracle_dimension`), for `members` of the 20 members of every phi-action over `episodes`
    episodes (the steps of part 1); and, with numba, one compiled product over a member's
    100 x 100 matrix in cache and the compiled phi-action of a near-consensus step, per member
    (microseconds)."""
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.dynamics.laplacian import FrozenLaplacian
    from agent_envs.envs import ENV_ID
    from agent_envs.integrators import phi_functions as pf

    captured: list[tuple[Any, ...]] = []
    original = pf._krylov

    def capture(a: Any, v: Any, order: int, symmetric: bool, rtol: float, max_dim: int,
                bounds: Any = None, add_product: Any = None) -> Any:  # fmt: skip
        if isinstance(a, FrozenLaplacian):
            if add_product is not None:  # SERB's F + sigma L dW, as the phi-action sees it
                v = v + add_product[1] * (a @ add_product[0])
            norms, widths, low = a.krylov_bounds() if bounds is None else bounds
            widths = np.full(a.shape[:-2], np.inf) if widths is None else widths
            pick = slice(None, None, max(1, a.shape[0] // members))
            captured.append((a.dense()[pick], np.array(v[pick]), order, rtol,
                             np.broadcast_to(norms, a.shape[:-2])[pick],
                             np.broadcast_to(widths, a.shape[:-2])[pick],
                             a.parts(), np.array(v), a.scale, a.peak, low))  # fmt: skip
            return original(a, v, order, symmetric, rtol, max_dim, bounds)
        return original(a, v, order, symmetric, rtol, max_dim, bounds, add_product)

    env = gym.make(ENV_ID, **env_kwargs("paper", "serb")).unwrapped
    action = np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape)
    pf._krylov = capture
    # the envs' fused step (phi-action and next kernel pass in one compiled call) does not go
    # through `_krylov`: off while capturing (the same phi-actions and states)
    from agent_envs.integrators import exponential

    fused_before = exponential.use_fused_step(False)
    try:
        for episode in range(episodes):
            env.reset(seed=episode)
            for _ in range(env.config.n_steps):
                env.step(action.astype(np.float32))
                # keep only the last step's whole batch (for the timing below)
                if len(captured) > 1:
                    captured[-2] = (*captured[-2][:6], captured[-2][-1])
    finally:
        exponential.use_fused_step(fused_before)
        pf._krylov = original
    count = [0]
    apply = pf._RowOperator.apply

    def counted(self: Any, rows: Any) -> Any:
        count[0] += 1
        return apply(self, rows)

    reached, oracle, step_of = [], [], []
    tridiagonals = []  # the oracle's T_m per sampled member and step (its one accepted check)
    pf._RowOperator.apply = counted
    try:
        for index, (dense, v, order, rtol, norms, widths, *_, low) in enumerate(captured):
            for j in range(dense.shape[0]):
                count[0] = 0
                bounds = (norms[j : j + 1], widths[j : j + 1], low)
                pf._lanczos_numpy(pf._RowOperator(dense[j : j + 1]), v[j : j + 1], order, rtol,
                                  100, bounds=bounds)  # fmt: skip
                reached.append(count[0])
                deflate = bool(np.isfinite(widths[j]))
                m, alphas, betas = _oracle_lanczos(dense[j], v[j, :, 0], order, rtol, deflate)
                oracle.append(m)
                tridiagonals.append((m, alphas, betas))
                step_of.append(index % env.config.n_steps)
    finally:
        pf._RowOperator.apply = apply
    reached_a, oracle_a, steps = np.array(reached), np.array(oracle), np.array(step_of)
    late, early = steps >= 10, steps < 3
    out = {
        "reached": float(reached_a.mean()),
        "reached_late": float(reached_a[late].mean()),
        "reached_early": float(reached_a[early].mean()),
        "oracle": float(oracle_a.mean()),
        "oracle_late": float(oracle_a[late].mean()),
        "oracle_early": float(oracle_a[early].mean()),
    }
    if pf.load_compiled():
        from numba import njit

        from agent_envs.native import lanczos as cl
        from agent_envs.native.kernel import lower_product as product

        @njit
        def products(p: Any, q: Any, w: Any, n: int, reps: int) -> None:
            for _ in range(reps):
                product(p, q, w, n)

        (p, s), v_all, scale, peak = captured[-1][6:10]
        from agent_envs.arrays import aligned_empty

        def aligned_copy(a: Any) -> Any:  # where the env's workspace keeps P: a cache line
            out = aligned_empty(a.shape)
            out[...] = a
            return out

        p0, q, w = aligned_copy(p[0]), np.ones(p.shape[-1]), np.empty(p.shape[-1])
        products(p0, q, w, p.shape[-1], 10)
        start = time.perf_counter()
        products(p0, q, w, p.shape[-1], 20000)
        out["product_us"] = 1e6 * (time.perf_counter() - start) / 20000
        out["pair_speedup"] = _pair_speedup(p0)
        members_all = p.shape[0]
        p_all = aligned_copy(p).reshape(members_all, *p.shape[-2:])
        p_all.flags.writeable = False
        s_all = np.ascontiguousarray(s).reshape(members_all, -1)
        rhs = np.ascontiguousarray(v_all).reshape(members_all, *v_all.shape[-2:])
        result, ok = np.empty(rhs.shape), np.empty(members_all, dtype=bool)

        def call() -> None:
            cl.frozen_lanczos(p_all, s_all, scale, rhs, 1, 1e-10, 100, pf.MAX_CHECK_STEP,
                              pf._NO_BOUNDS, pf._NO_BOUNDS, pf._NO_BOUNDS, peak, result, ok,
                              pf._NO_EXTRA, 0.0)  # fmt: skip

        out["member_us"] = 1e6 * interleaved({"call": call}, 200, 5)["call"] / members_all
        out.update(_compiled_bounds(env, captured[min(2, len(captured) - 1)]))
        out.update(_recurrence_and_checks(tridiagonals, p.shape[-1]))
    return out


def _pair_speedup(p: np.ndarray, rounds: int = 30, reps: int = 1000) -> float:
    """Two vectors' products over one P (aligned, in cache): two `lower_product` passes / one
    `lower_product_pair` pass (d > 1: the Lanczos's k columns and the kernel pass's P x take
    pairs), the median of the per-round ratios over alternating rounds."""
    from numba import njit

    from agent_envs.native.kernel import lower_product, lower_product_pair

    @njit
    def singles(p: Any, q: Any, w: Any, n: int, reps: int) -> None:
        for _ in range(reps):
            lower_product(p, q[0], w[0], n)
            lower_product(p, q[1], w[1], n)

    @njit
    def pairs(p: Any, q: Any, w: Any, n: int, reps: int) -> None:
        for _ in range(reps):
            lower_product_pair(p, q[0], q[1], w[0], w[1], n)

    n = p.shape[-1]
    q = np.random.default_rng(0).standard_normal((2, n))
    w = np.empty((2, n))
    singles(p, q, w, n, 1)
    pairs(p, q, w, n, 1)
    ratios = []
    for _ in range(rounds):
        start = time.perf_counter()
        singles(p, q, w, n, reps)
        middle = time.perf_counter()
        pairs(p, q, w, n, reps)
        ratios.append((middle - start) / (time.perf_counter() - middle))
    return float(np.median(ratios))


def _ql_check_runs() -> Callable[..., tuple[int, float]]:
    """A compiled loop of `reps` QL checks of one T_m (`_phi_of_tridiagonal`, and with
    `with_bound` its error bound at the top eigenvalue, `_error_bound`): (the number of
    rotations, the sum of the bounds). Built on first use (numba is imported only here)."""
    from numba import njit

    from agent_envs.native import lanczos as cl

    @njit
    def runs(alphas: Any, betas: Any, m: int, fact: Any, reps: int, with_bound: bool) -> Any:
        out, d, e, rows = np.empty(m), np.empty(m), np.empty(m), np.empty((2, m))
        size = 2 * m * m + 8
        rot_c, rot_s, phis = np.empty(size), np.empty(size), np.empty(m)
        rot_at = np.empty(size, dtype=np.int64)
        count, acc = 0, 0.0
        for _ in range(reps):
            count = cl._phi_of_tridiagonal(alphas, betas, m, 0, 1, fact, out, d, e, rows, rot_c,
                                           rot_s, rot_at, phis)[2]  # fmt: skip
            if with_bound:
                acc += cl._error_bound(d, rows, phis, m, 1, fact, d[m - 1])
        return count, acc

    return runs


def _recurrence_and_checks(tridiagonals: list[tuple[Any, ...]], n: int) -> dict[str, float]:
    """Per member and step, what a Lanczos phi-action that stops at the oracle's dimension m
    with a single check must run besides its products: m iterations of the compiled
    recurrence (`_scale_dot` and two `_axpy_dot` on n-vectors) and one QL check with its error
    bound at m (`_phi_of_tridiagonal`, `_error_bound`) on the oracle's own T_m; microseconds
    (means over the sampled member-steps)."""
    from numba import njit

    from agent_envs.native import lanczos as cl

    @njit
    def recurrence(w: Any, s: Any, q: Any, qp: Any, n: int, reps: int) -> float:
        acc = 0.0
        for _ in range(reps):
            alpha = cl._scale_dot(w, s, q, 1.0, n)
            proj = cl._axpy_dot(w, -1e-3 * alpha, q, qp, n)
            acc += cl._axpy_dot(w, -1e-3 * proj, qp, w, n)
        return acc

    checks = _ql_check_runs()

    rng = np.random.default_rng(0)
    w, s, q, qp = (rng.uniform(0.5, 1.0, n) for _ in range(4))
    reps = 20000
    recurrence(w.copy(), s, q, qp, n, 1)
    iteration_us = (
        1e6
        * interleaved({"rec": lambda: recurrence(w.copy(), s, q, qp, n, reps)}, 1, 5)["rec"]
        / reps
    )
    fact = cl._factorials(cl.TAYLOR_TERMS + 3)
    check_us = []
    for m, alphas, betas in tridiagonals:
        t_a, t_b = alphas.reshape(m, 1), np.append(betas, 0.0)[:m].reshape(m, 1)
        checks(t_a, t_b, m, fact, 1, True)
        start = time.perf_counter()
        checks(t_a, t_b, m, fact, 50, True)
        check_us.append(1e6 * (time.perf_counter() - start) / 50)
    return {"iteration_us": iteration_us, "check_us": float(np.mean(check_us))}


def _compiled_bounds(env: Any, early: tuple[Any, ...]) -> dict[str, float]:
    """What the compiled step runs against, per member: the kernel pass (`cucker_smale_drift`)
    on the env's last state, its N (N + 1) / 2 divisions alone (`_lower_row`: the rows of P's
    lower triangle, without the sums s = P 1, P x and the drift), and one QL check
    (`_phi_of_tridiagonal`) of the T_m an early step's first member needs (`early`: a capture
    of `worker_krylov`, m its oracle dimension): microseconds, and ns per QL rotation."""
    from numba import njit

    from agent_envs import arrays
    from agent_envs.native import kernel as ck
    from agent_envs.native import lanczos as cl

    @njit
    def kernel_passes(x: Any, w: float, a2: float, p: Any, s: Any, f: Any, reps: int) -> None:
        for _ in range(reps):
            ck.cucker_smale_drift(x, w, a2, p, s, f)

    @njit
    def division_passes(xt: Any, w: float, a2: float, p: Any, n: int, d: int, reps: int) -> None:
        for _ in range(reps):
            for k in range(n):
                ck._lower_row(xt, k, w, a2, p[k], n, d)

    ql_checks = _ql_check_runs()

    model = env.episode.model
    x = np.ascontiguousarray(env.episode.positions[:1])  # one member, (1, N, d)
    _, n, d = x.shape
    w, a2 = model.compiled_pass_parameters(x)
    p, s, f = arrays.aligned_empty((1, n, n)), np.empty((1, n)), np.empty(x.shape)
    xt = np.ascontiguousarray(x[0].T)
    reps = 2000
    kernel_passes(x, w, a2, p, s, f, 1)
    division_passes(xt, w, a2, p[0], n, d, 1)

    def timed(call: Callable[[], None]) -> float:
        start = time.perf_counter()
        call()
        return 1e6 * (time.perf_counter() - start) / reps

    found = interleaved(
        {
            "kernel": lambda: kernel_passes(x, w, a2, p, s, f, reps),
            "divisions": lambda: division_passes(xt, w, a2, p[0], n, d, reps),
        },
        1,
        5,
    )
    out = {"kernel_pass_us": 1e6 * found["kernel"] / reps,
           "divisions_us": 1e6 * found["divisions"] / reps}  # fmt: skip
    # an early step's T_m: the deflated Lanczos of its first member to its oracle dimension
    m, alphas, betas = _oracle_lanczos(early[0][0], early[1][0, :, 0], 1, 1e-10, True)
    t_a, t_b = alphas.reshape(m, 1), np.append(betas, 0.0).reshape(m, 1)  # (e[m - 1]: scratch)
    fact = cl._factorials(cl.TAYLOR_TERMS + 2)
    rotations = ql_checks(t_a, t_b, m, fact, 1, False)[0]
    ql_us = timed(lambda: ql_checks(t_a, t_b, m, fact, reps, False))
    out.update(ql_m=float(m), ql_rotations=float(rotations), ql_us=ql_us)
    return out


def worker_device(
    device: str, num_envs: int, setting: str, integrator: str, n_paths: int, steps: int, rounds: int
) -> dict[str, float]:
    """The native vector env on `device` ("cpu": numpy; else torch there), B = `num_envs`.

    Fresh process: `setup` is import + (CUDA context) + make + reset; `cold` the seconds per
    step of the first `steps` steps; `warm` the median over `rounds` blocks of the same steps
    (reset with seed 0 first). `draws` and `advance` are the shares of the warm steps spent in
    the host's Brownian draws (each env's numpy generator, as its single twin) and in the
    integrator's batched step (`_advance`, synchronized with the device); `peak_gib` the device
    memory torch allocated at most.
    """
    start = time.perf_counter()
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.envs import ENV_ID
    from agent_envs.envs import vector_env as vector_module

    sync: Callable[[], None] = lambda: None  # noqa: E731
    if device != "cpu":
        import torch

        torch.zeros(1, device=device)  # the CUDA context, in the setup time
        if device.startswith("cuda"):
            sync = torch.cuda.synchronize
    kwargs = env_kwargs(setting, integrator, n_paths=n_paths)
    env = gym.make_vec(
        ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point", device=device, **kwargs
    ).unwrapped
    env.reset(seed=0)
    sync()
    setup = time.perf_counter() - start
    spent = {"draws": 0.0, "advance": 0.0}
    # the draws' function as the vector env calls it (`fill_brownian_increments`, one call per
    # step; `brownian_increments` per env in trees before it)
    draw_name = next(
        name
        for name in ("fill_brownian_increments", "brownian_increments")
        if hasattr(vector_module, name)
    )
    draw, advance = getattr(vector_module, draw_name), env._advance

    def timed_draw(*args: Any) -> Any:
        t0 = time.perf_counter()
        try:
            return draw(*args)
        finally:
            spent["draws"] += time.perf_counter() - t0

    def timed_advance(*args: Any) -> Any:
        t0 = time.perf_counter()
        try:
            out = advance(*args)
            sync()
            return out
        finally:
            spent["advance"] += time.perf_counter() - t0

    setattr(vector_module, draw_name, timed_draw)
    env._advance = timed_advance
    actions = np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape)
    actions = actions.astype(np.float32)

    def block() -> float:
        t0 = time.perf_counter()
        for _ in range(steps):
            env.step(actions)
        return (time.perf_counter() - t0) / steps

    cold = block()
    warm, shares = [], {"draws": [], "advance": []}
    for _ in range(rounds):
        env.reset(seed=0)
        spent.update(draws=0.0, advance=0.0)
        seconds = block()
        warm.append(seconds)
        for key in shares:
            shares[key].append(spent[key] / (steps * seconds))
    out = {
        "setup": setup,
        "cold": cold,
        "warm": float(np.median(warm)),
        "draws": float(np.median(shares["draws"])),
        "advance": float(np.median(shares["advance"])),
    }
    if device.startswith("cuda"):
        import torch

        out["peak_gib"] = torch.cuda.max_memory_allocated(device) / 2**30
    return out


def worker_accounting(episodes: int = 20, batch: int = 64, batch_steps: int = 300) -> dict:
    """Where an env step's time goes, call by call (this tree; `time.perf_counter` around each
    call, about 0.3 us each): the paper single env, SERB and EM episodes alternating, per step,
    and the compiled call of SERB's steps 0-2 against steps >= 10; the native vector env at
    B = `batch`, 1 path, SERB, per batch step (its compiled step: prologue, draws, the
    integrator's fused step, epilogue). Microseconds."""
    import gymnasium as gym

    import agent_envs  # noqa: F401
    from agent_envs.envs import ENV_ID, episode, vector_env

    out: dict[str, float] = {}
    envs, actions = {}, {}
    for integrator in ("serb", "em"):
        env = gym.make(ENV_ID, **env_kwargs("paper", integrator)).unwrapped
        envs[integrator] = env
        actions[integrator] = (
            np.random.default_rng(1).uniform(-0.5, 0.5, env.action_space.shape).astype(np.float32)
        )
    timers = {k: _CallTimes() for k in envs}
    per_step = {k: np.zeros((episodes, 50)) for k in envs}
    totals = dict.fromkeys(envs, 0.0)
    for ep in range(episodes + 2):
        for integrator, env in envs.items():
            times = timers[integrator]
            model, stepper = env.episode.model, env.episode.integrator
            times.wrap(episode, "advance_paths", "advance_paths")
            times.wrap(stepper, "step", "integrator step")
            times.wrap(episode, "diverged_paths", "diverged_paths")
            times.wrap(episode, "mean_interaction_drift", "mean drift")
            for name in ("drift_and_linearization", "adopt_linearization", "drift"):
                times.wrap(model, name, name)
            _wrap_compiled(times)
            before_reset = dict(times.seconds)
            env.reset(seed=ep)
            times.seconds = before_reset  # (only the steps' calls count)
            for k in range(env.config.n_steps):
                before = dict(times.seconds) if ep >= 2 else None
                start = time.perf_counter()
                env.step(actions[integrator])
                spent = time.perf_counter() - start
                if before is None:
                    continue
                totals[integrator] += spent
                compiled = times.seconds.get("compiled", 0.0) - before.get("compiled", 0.0)
                per_step[integrator][ep - 2, k] = compiled
            times.restore()
            if ep < 2:
                times.seconds.clear()
    for integrator, times in timers.items():
        n = episodes * 50
        out[f"{integrator}/total"] = 1e6 * totals[integrator] / n
        for key, value in times.seconds.items():
            out[f"{integrator}/{key}"] = 1e6 * value / n
        m = per_step[integrator]
        out[f"{integrator}/compiled steps 0-2"] = 1e6 * float(np.median(m[:, :3]))
        out[f"{integrator}/compiled steps 10-49"] = 1e6 * float(np.median(m[:, 10:]))

    kwargs = env_kwargs("paper", "serb", n_paths=1)
    native = gym.make_vec(
        ENV_ID, num_envs=batch, vectorization_mode="vector_entry_point", **kwargs
    ).unwrapped
    native.reset(seed=0)
    acts = np.random.default_rng(1).uniform(-0.5, 0.5, (batch, 100)).astype(np.float32)
    for _ in range(100):
        native.step(acts)
    times = _CallTimes()
    for name, key in (("_controls", "actions and controls"), ("_observations", "observation"),
                      ("_state_info", "info arrays"), ("_advance", "advance"),
                      ("_step_compiled", "compiled step")):  # fmt: skip
        times.wrap(native, name, key)
    times.wrap(native.integrator, "fused_step", "fused step")
    times.wrap(vector_env, "mean_running_cost", "running cost")
    times.wrap(vector_env, "fill_brownian_increments", "draws")
    times.wrap(episode, "diverged_paths", "diverged_paths")
    times.wrap(episode, "mean_interaction_drift", "mean drift")
    _wrap_compiled(times)
    start = time.perf_counter()
    for _ in range(batch_steps):
        native.step(acts)
    out["native/total"] = 1e6 * (time.perf_counter() - start) / batch_steps
    times.restore()
    for key, value in times.seconds.items():
        out[f"native/{key}"] = 1e6 * value / batch_steps
    return out


WORKERS = {
    "cold": worker_cold,
    "ratios": worker_ratios,
    "krylov": worker_krylov,
    "vector": worker_vector,
    "threads": worker_threads,
    "ppo": worker_ppo,
    "device": worker_device,
    "accounting": worker_accounting,
}


# ----------------------------------------------------------------------------- driver
def run_worker(python: str, name: str, **kwargs: Any) -> dict[str, float]:
    """Run a worker in a fresh process of `python` and return its JSON answer."""
    cmd = [python, os.path.abspath(__file__), "--worker", name, "--worker-args", json.dumps(kwargs)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"worker {name} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def fmt_pair(after: float, before: float | None, spec: str = ",.0f") -> str:
    if before is None:
        return format(after, spec)
    return f"{format(after, spec)} ({format(before, spec)})"


def device_table(device: str, num_envs: int, steps: int, rounds: int, cpu_max_envs: int) -> None:
    """Part 5: the native vector env on `device` at B = `num_envs` (torch), this tree only,
    against the numpy native env on this host's CPU (one thread) at B = min(`num_envs`,
    `cpu_max_envs`), halved until its dense matrices fit `DENSE_MEMORY_BUDGET_BYTES` (beyond it
    numpy goes matrix-free, which the torch env never does). numpy steps its systems one by
    one, so its env-steps/s hardly depend on B past a few envs (part 3)."""
    import torch

    from agent_envs.dynamics.operators import DENSE_MEMORY_BUDGET_BYTES, dense_bytes

    if device.startswith("cuda") and not torch.cuda.is_available():
        print(f"## 5. {device}: torch sees no CUDA device here; skipped\n")
        return
    name = torch.cuda.get_device_name(device) if device.startswith("cuda") else device
    print(
        f"## 5. Native vector env on {name} (torch, float64), B = {num_envs}, against numpy on"
        f" this host's CPU (one thread)\n"
    )
    print(
        f"cold = the first {steps} steps of a fresh process (after make + reset), warm = the"
        f" median of {rounds} blocks of the same steps; shares of the warm step: the host's"
        " Brownian draws (each env's numpy generator) and the integrator's batched step\n"
    )
    print(
        "| setting | integrator | paths | device env-steps/s (warm) | cold/warm | setup (s) |"
        " draws | integrator step | peak GiB | CPU B | CPU env-steps/s | device / CPU |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for setting in SETTINGS:
        n = SETTINGS[setting]["n_agents"]
        for n_paths in (1, 20):
            cpu_envs = min(num_envs, cpu_max_envs)
            while cpu_envs > 1 and (
                dense_bytes(n, 1, cpu_envs * n_paths, "frozen") > DENSE_MEMORY_BUDGET_BYTES
            ):
                cpu_envs //= 2
            for integrator in ("serb", "em"):
                common = {"setting": setting, "integrator": integrator, "n_paths": n_paths}
                common.update(steps=steps, rounds=rounds)
                try:
                    dev = run_worker(
                        sys.executable, "device", device=device, num_envs=num_envs, **common
                    )
                    cpu = run_worker(
                        sys.executable, "device", device="cpu", num_envs=cpu_envs, **common
                    )
                except RuntimeError as err:  # one failed row (out of memory, say) is reported
                    last = str(err).strip().splitlines()[-1][:200]
                    print(f"| {setting} | {integrator} | {n_paths} | failed: {last} |", flush=True)
                    continue
                dev_rate, cpu_rate = num_envs / dev["warm"], cpu_envs / cpu["warm"]
                print(
                    f"| {setting} | {integrator} | {n_paths} | {dev_rate:,.0f} | "
                    f"{dev['cold'] / dev['warm']:.2f} | {dev['setup']:.1f} | "
                    f"{100 * dev['draws']:.0f} % | {100 * dev['advance']:.0f} % | "
                    f"{dev.get('peak_gib', float('nan')):.1f} | {cpu_envs} | {cpu_rate:,.0f} | "
                    f"{dev_rate / cpu_rate:.1f} |",
                    flush=True,
                )
    print()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5, help="rounds (medians)")
    parser.add_argument("--ppo-timesteps", type=int, default=4096)
    parser.add_argument("--baseline-python", default=None, help="interpreter of the 'before'")
    parser.add_argument(
        "--device", default=None, help="part 5: the native vector env on this torch device"
    )
    parser.add_argument("--device-envs", type=int, default=4096, help="part 5: B on the device")
    parser.add_argument(
        "--device-cpu-envs", type=int, default=512, help="part 5: B of numpy on the CPU, at most"
    )
    parser.add_argument("--device-steps", type=int, default=10, help="part 5: steps per block")
    parser.add_argument("--skip", nargs="*", default=[], choices=list(WORKERS))
    parser.add_argument("--worker", choices=list(WORKERS), help=argparse.SUPPRESS)
    parser.add_argument("--worker-args", default="{}", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(WORKERS[args.worker](**json.loads(args.worker_args))))
        return 0

    pythons = {"after": sys.executable}
    if args.baseline_python:
        pythons["before"] = args.baseline_python
    has_before = "before" in pythons
    r = args.rounds
    note = " (before in brackets)" if has_before else ""
    print(f"Throughput, OPENBLAS_NUM_THREADS=1, medians of {r} rounds{note}\n")

    if "cold" not in args.skip:
        print("## 1. Env steps/s, first 100 steps of a fresh process (cold) and warm\n")
        print(
            "| setting | integrator | cold steps/s | warm steps/s | cold/warm |"
            " import + make + reset (s) |"
        )
        print("|---|---|---|---|---|---|")
        for setting in SETTINGS:
            for integrator in ("serb", "em"):
                # `r` fresh processes per interpreter: medians of their cold and warm figures
                res = {}
                for k, py in pythons.items():
                    runs = [
                        run_worker(py, "cold", setting=setting, integrator=integrator, rounds=r)
                        for _ in range(r)
                    ]
                    res[k] = {
                        key: float(np.median([run[key] for run in runs]))
                        for key in ("cold", "warm", "setup")
                    }
                    res[k]["ratio"] = float(np.median([run["cold"] / run["warm"] for run in runs]))
                a, b = res["after"], res.get("before")
                print(
                    f"| {setting} | {integrator} | "
                    f"{fmt_pair(1 / a['cold'], b and 1 / b['cold'])} | "
                    f"{fmt_pair(1 / a['warm'], b and 1 / b['warm'])} | "
                    f"{fmt_pair(a['ratio'], b and b['ratio'], '.2f')} | "
                    f"{fmt_pair(a['setup'], b and b['setup'], '.2f')} |"
                )
        print()

    if "ratios" not in args.skip:
        res = {k: run_worker(py, "ratios", rounds=r) for k, py in pythons.items()}
        print("## 2. Ratios in one process (warm, paper setting unless said)\n")
        print("| ratio | value | ms per step (numerator, denominator) |")
        print("|---|---|---|")
        for label, num, den in (
            ("SERB env step / EM env step", "serb_env", "em_env"),
            ("EM env step / plain numpy kernel + drift", "em_env", "plain"),
            ("EM env step / in-place numpy kernel + drift", "em_env", "inplace"),
            ("EM env step / the env's kernel + drift (compiled with numba)", "em_env", "floor"),
            ("one SERB step / one EM step (N = 100, 1 path)", "serb_bare_1", "em_bare_1"),
            (
                "SERB / EM, native vector env of 16 paper envs (20 paths each)",
                "serb_native",
                "em_native",
            ),
        ):
            a, b = res["after"], res.get("before")
            print(
                f"| {label} | {fmt_pair(a[num] / a[den], b and b[num] / b[den], '.2f')} | "
                f"{fmt_pair(1e3 * a[num], b and 1e3 * b[num], '.3f')}, "
                f"{fmt_pair(1e3 * a[den], b and 1e3 * b[den], '.3f')} |"
            )
        a, b = res["after"], res.get("before")
        floors = {
            k: (v["em_env"] + v["krylov_products"] * v["matrix_pass"]) / v["em_env"]
            for k, v in res.items()
        }
        products = fmt_pair(a["krylov_products"], b and b["krylov_products"], ".1f")
        one_pass = fmt_pair(1e3 * a["matrix_pass"], b and 1e3 * b["matrix_pass"], ".3f")
        print(
            f"\nSERB env step: {products} Lanczos products per step (mean over the 100 steps of"
            f" part 1); one product of each of the 20 members' kernel matrices (compiled, P's"
            f" lower triangle, in the same rounds as the steps) {one_pass} ms; the products"
            " alone: SERB / EM >= (EM step + products x pass) / EM step ="
            f" {fmt_pair(floors['after'], floors.get('before'), '.2f')}"
        )
        bounds = {
            k: (v["em_total"] + v["serb_compiled"] - v["em_compiled"]) / v["em_total"]
            for k, v in res.items()
            if "serb_compiled" in v
        }
        alone = {k: v["serb_compiled"] / v["em_compiled"] for k, v in res.items() if k in bounds}
        if "after" in bounds:
            print(
                "\nThe compiled calls (kernel pass, fused phi-action; measured inside the steps,"
                f" alternating rounds): SERB {1e3 * a['serb_compiled']:.3f} of"
                f" {1e3 * a['serb_total']:.3f} ms, EM {1e3 * a['em_compiled']:.3f} of"
                f" {1e3 * a['em_total']:.3f} ms; SERB / EM with no interpreter time beyond EM's"
                " = (EM step + SERB's compiled time - EM's) / EM step ="
                f" {fmt_pair(bounds['after'], bounds.get('before'), '.2f')}; the compiled"
                f" calls alone (no interpreter time in either step): SERB / EM ="
                f" {fmt_pair(alone['after'], alone.get('before'), '.2f')}"
            )
        per_product = {
            k: (v["serb_bare_1"] - v["em_bare_1"]) / v["krylov_products_1"] for k, v in res.items()
        }
        products_1 = fmt_pair(a["krylov_products_1"], b and b["krylov_products_1"], ".1f")
        before_ms = per_product.get("before")
        cost = fmt_pair(1e3 * per_product["after"], before_ms and 1e3 * before_ms, ".3f")
        print(
            f"\nOne SERB step, N = 100, 1 path: {products_1} Lanczos products per step; its cost"
            " beyond the EM step per product (the interpreter's share: numpy calls on 100-vectors)"
            f" {cost} ms"
        )
        print()

    if "krylov" not in args.skip:
        k = run_worker(sys.executable, "krylov")
        print("## 2b. Krylov dimensions per member and step (paper SERB env, this tree)\n")
        print("| | mean | steps >= 10 (near consensus) | steps 0-2 |")
        print("|---|---|---|---|")
        for label, key in (("reached (rtol 1e-10)", "reached"), ("oracle", "oracle")):
            print(f"| {label} | {k[key]:.2f} | {k[key + '_late']:.2f} | {k[key + '_early']:.1f} |")
        if "product_us" in k:
            print(
                f"\nOne compiled product over a member's 100 x 100 matrix in cache: "
                f"{k['product_us']:.2f} us; the compiled phi-action of a near-consensus step: "
                f"{k['member_us']:.2f} us per member"
            )
            if "pair_speedup" in k:
                print(
                    "Two vectors' products in one pass over P (`lower_product_pair`: d > 1, the"
                    " Lanczos's columns and the kernel pass's P x) against two passes:"
                    f" {k['pair_speedup']:.2f}x (median of alternating rounds)"
                )
            if "kernel_pass_us" in k:
                print(
                    f"The compiled kernel pass of one member: {k['kernel_pass_us']:.2f} us, of"
                    f" which its {100 * 101 // 2:,} divisions alone (the rows of P's lower"
                    f" triangle) {k['divisions_us']:.2f} us. One QL check at an early step's"
                    f" dimension (m = {k['ql_m']:.0f}): {k['ql_us']:.2f} us,"
                    f" {k['ql_rotations']:.0f} rotations,"
                    f" {1e3 * k['ql_us'] / max(k['ql_rotations'], 1):.1f} ns each"
                )
            if "ratios" not in args.skip:
                # the EM step and the products' pass of part 2's rounds (one machine speed)
                em, one_pass = res["after"]["em_env"], res["after"]["matrix_pass"]
                for label, dims in (("the oracle", k["oracle"]), ("the reached", k["reached"])):
                    extra = (dims + 1) * one_pass  # + the noise product
                    print(
                        f"Products alone at {label} dimension (+ the noise product; part 2's"
                        f" pass and EM step): SERB / EM >= {(em + extra) / em:.2f}"
                    )
                if "check_us" in k:
                    # the recurrence and the one check in units of this worker's product, at
                    # part 2's machine speed (its pass is 20 members' products)
                    scale = one_pass / 20 / (1e-6 * k["product_us"])
                    members = 20 * 1e-6 * scale * (k["oracle"] * k["iteration_us"] + k["check_us"])
                    bound = (em + (k["oracle"] + 1) * one_pass + members) / em
                    print(
                        f"Products, recurrence ({k['iteration_us']:.2f} us an iteration) and one"
                        f" accepted check per member and step ({k['check_us']:.2f} us on average"
                        f" at the oracle's T_m), at the oracle dimension: SERB / EM >= {bound:.2f}"
                        " (a Lanczos that knew where to stop, with no other work and no"
                        " interpreter time beyond EM's)"
                    )
        print()

    if "vector" not in args.skip:
        print("## 3. Native vector env (SERB, paper setting) vs B single envs in a loop\n")
        batches, paths = [1, 16, 64], [1, 20]
        res = {
            k: run_worker(py, "vector", batches=batches, paths=paths, rounds=r)
            for k, py in pythons.items()
        }
        print(
            "| paths | B | native env-steps/s | loop env-steps/s | native / loop |"
            " kernel + drift share of the native step (the env's pass) |"
        )
        print("|---|---|---|---|---|---|")
        for p in paths:
            for b in batches:
                a, o = res["after"], res.get("before")
                key_n, key_l, key_f = f"native/B{b}/P{p}", f"loop/B{b}/P{p}", f"floor/B{b}/P{p}"
                print(
                    f"| {p} | {b} | {fmt_pair(a[key_n], o and o[key_n])} | "
                    f"{fmt_pair(a[key_l], o and o[key_l])} | "
                    f"{fmt_pair(a[key_n] / a[key_l], o and o[key_n] / o[key_l], '.2f')} | "
                    f"{fmt_pair(100 * a[key_n] / a[key_f], o and 100 * o[key_n] / o[key_f])} % |"
                )
        b = max(batches)
        a, o = res["after"], res.get("before")
        key_n, key_s = f"native/B{b}/P1", f"sync/B{b}/P1"
        print(
            f"\nSyncVectorEnv, B = {b}, 1 path: {fmt_pair(a[key_s], o and o[key_s])} env-steps/s;"
            f" native / Sync = {fmt_pair(a[key_n] / a[key_s], o and o[key_n] / o[key_s], '.2f')}"
        )
        key_p = f"numpy_step/B{b}/P1"
        if key_p in a:
            print(
                f"The same native env with its numpy step (compiled prologue and epilogue off), in"
                f" the same rounds: {a[key_p]:,.0f} env-steps/s; compiled / numpy step ="
                f" {a[key_n] / a[key_p]:.2f}; numpy step / Sync = {a[key_p] / a[key_s]:.2f}"
            )
        key_c = f"native_compiled/B{b}/P1"
        if key_c in a:
            native_total, sync_total = a[f"native_total/B{b}/P1"], a[f"sync_total/B{b}/P1"]
            compiled, draws = a[key_c], a.get(f"native_draws/B{b}/P1", 0.0)
            print(
                "In alternating rounds, per env-step: the native step"
                f" {1e6 * native_total:.1f} us, of which its compiled calls {1e6 * compiled:.1f}"
                f" us and its Brownian draws {1e6 * draws:.1f} us (each env's own generator, as"
                f" its single twin: the bit-for-bit contract); Sync's step {1e6 * sync_total:.1f}"
                f" us. native / Sync there {sync_total / native_total:.2f}; with no interpreter"
                f" time at all <= {sync_total / compiled:.2f}, with none but the draws <="
                f" {sync_total / (compiled + draws):.2f}"
            )
        print()

    if "threads" not in args.skip:
        res = run_worker(sys.executable, "threads", rounds=r)
        most = int(res["threads"])
        print(f"## 3b. The native vector env on {most} threads (`num_threads`, this tree)\n")
        if most < 2:
            print("numba allows one thread here (NUMBA_NUM_THREADS, or no numba): skipped\n")
        else:
            print(
                f"| integrator | paths | B | baseline | native, 1 thread | native, {most} threads"
                f" | native / baseline, 1 thread | {most} threads | {most} threads / 1 |"
            )
            print("|---|---|---|---|---|---|---|---|---|")
            for integrator, b, n_paths in (("serb", 64, 1), ("serb", 16, 20), ("em", 64, 1)):
                key = f"{integrator}/B{b}/P{n_paths}"
                one, many, base = (
                    res[f"native1/{key}"],
                    res[f"native{most}/{key}"],
                    res[f"baseline/{key}"],
                )
                name = "SyncVectorEnv" if n_paths == 1 else f"{b} single envs in a loop"
                print(
                    f"| {integrator} | {n_paths} | {b} | {name}: {base:,.0f} | {one:,.0f} |"
                    f" {many:,.0f} | {one / base:.2f} | {many / base:.2f} | {many / one:.2f} |"
                )
            print(
                "\nThe paper single env (20 paths), env steps/s: SERB"
                f" {res['single1/serb']:,.0f} on 1 thread, {res[f'single{most}/serb']:,.0f} on"
                f" {most}; EM {res['single1/em']:,.0f} and {res[f'single{most}/em']:,.0f}; SERB"
                f" / EM (step time) {res['single1/em'] / res['single1/serb']:.2f} on 1 thread,"
                f" {res[f'single{most}/em'] / res[f'single{most}/serb']:.2f} on {most}"
            )
            print(
                "\n(env-steps/s, interleaved rounds in one process. The issue's targets are"
                " the one-thread ratios of part 3; threads add the machine's other cores to the"
                " compiled passes, bit for bit the same results.)\n"
            )

    if "ppo" not in args.skip:
        print(f"## 4. PPO on NativeVecEnv, paper setting, {args.ppo_timesteps} timesteps\n")
        res = {k: run_worker(py, "ppo", timesteps=args.ppo_timesteps) for k, py in pythons.items()}
        a, b = res["after"], res.get("before")
        print("| env-steps/s | share of time in the env | n_envs |")
        print("|---|---|---|")
        print(
            f"| {fmt_pair(a['steps_per_s'], b and b['steps_per_s'], ',.1f')} | "
            f"{fmt_pair(100 * a['env_share'], b and 100 * b['env_share'], '.0f')} % | "
            f"{a['n_envs']:.0f} |"
        )
        if b:
            print(f"\nPPO after / before: {a['steps_per_s'] / b['steps_per_s']:.2f}x")
        from agent_envs.dynamics.laplacian import max_compiled_threads

        most = max_compiled_threads()
        if most > 1:  # this tree, the native env on every thread numba allows
            one = run_worker(sys.executable, "ppo", timesteps=args.ppo_timesteps)
            many = run_worker(sys.executable, "ppo", timesteps=args.ppo_timesteps, threads=most)
            print(
                f"\nThis tree with the native env on {most} threads: {many['steps_per_s']:,.1f}"
                f" env-steps/s (env share {100 * many['env_share']:.0f} %) against"
                f" {one['steps_per_s']:,.1f} (env share {100 * one['env_share']:.0f} %) on one"
                f" thread in a process run just before it:"
                f" {many['steps_per_s'] / one['steps_per_s']:.2f}x"
            )
        print()

    if "accounting" not in args.skip:
        acc = run_worker(sys.executable, "accounting")
        print("## 6. Where a step's time goes, call by call (this tree)\n")
        print("Paper single env, SERB and EM episodes alternating, microseconds per env step")
        print("(inclusive: a call's time contains the calls inside it):\n")
        print("| call | SERB | EM |")
        print("|---|---|---|")
        keys = ("total", "advance_paths", "integrator step", "compiled in integrator step",
                "mean drift", "compiled in mean drift", "diverged_paths",
                "drift_and_linearization", "adopt_linearization", "drift")  # fmt: skip
        for key in keys:
            cells = [acc.get(f"{k}/{key}") for k in ("serb", "em")]
            if any(c is not None for c in cells):
                shown = " | ".join("" if c is None else f"{c:.1f}" for c in cells)
                print(f"| {key} | {shown} |")
        if "serb/compiled" in acc:
            python = {k: acc[f"{k}/total"] - acc[f"{k}/compiled"] for k in ("serb", "em")}
            print(
                f"\nCompiled: SERB {acc['serb/compiled']:.0f}, EM {acc['em/compiled']:.0f} us per"
                f" step ({(acc['serb/compiled'] - acc['em/compiled']) / 20:.1f} us more per"
                f" member); SERB's whole compiled call {acc['serb/compiled steps 0-2']:.0f} us at"
                f" an episode's steps 0-2 against {acc['serb/compiled steps 10-49']:.0f} at steps"
                f" 10-49 (medians). Interpreter and numpy: SERB {python['serb']:.0f}, EM"
                f" {python['em']:.0f} us per step."
            )
        print("\nNative vector env, B = 64, 1 path, SERB, microseconds per batch step")
        print("(inclusive; a compiled call is charged to the innermost call it ran in):\n")
        print("| call | us |")
        print("|---|---|")
        for key, label in (
            ("total", "total"),
            ("compiled step", "compiled step (`_step_compiled`)"),
            ("compiled in compiled step", "its prologue and epilogue (compiled)"),
            ("fused step", "the integrator's fused step"),
            ("compiled in fused step", "its compiled pass"),
            ("advance", "numpy step's advance (autoresets, fallbacks)"),
            ("compiled in advance", "its compiled passes"),
            ("diverged_paths", "diverged_paths"),
            ("mean drift", "mean drift"),
            ("draws", "draws"),
            ("actions and controls", "actions and controls"),
            ("running cost", "running cost"),
            ("observation", "observation"),
            ("info arrays", "info arrays"),
        ):
            if f"native/{key}" in acc:
                print(f"| {label} | {acc[f'native/{key}']:.1f} |")
        if "native/compiled" in acc:
            rest = acc["native/total"] - acc["native/compiled"] - acc.get("native/draws", 0.0)
            print(
                f"\nCompiled calls {acc['native/compiled']:.0f} us, draws"
                f" {acc.get('native/draws', 0.0):.0f} us, the rest (interpreter, numpy and these"
                f" timers) {rest:.0f} us per batch step."
            )
        print()

    if args.device and "device" not in args.skip:
        device_table(args.device, args.device_envs, args.device_steps, r, args.device_cpu_envs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
