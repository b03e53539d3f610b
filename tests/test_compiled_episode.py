"""The single envs' compiled step (`agent_envs.envs.compiled_episode`) against their numpy step.

The Gymnasium and the PettingZoo env step on the compiled envelope where their plan says so;
an env made with the path "step" switched off steps with the numpy calls (its plan's envelope
is "numpy"). Both must give the same observations, rewards, flags, infos and states bit for
bit: over whole episodes (truncation at the horizon, resets), divergence, every observation
layout and action basis, d = 1 and 2, one and several paths, a fused step that gives up, and
with every compiled path off.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from test_step_plan import switched_off

from agent_envs import swarm_v0
from agent_envs.envs import fast_step
from agent_envs.envs.compiled_agents import agents_same_as_numpy, combined_same_as_separate
from agent_envs.envs.swarm_env import ENV_ID
from agent_envs.native import loader

pytestmark = pytest.mark.skipif(
    not fast_step.load_compiled_step(), reason="the compiled step needs numba"
)

DIVERGING = {"n_steps": 10, "max_control": 10.0, "divergence_threshold": 2.5}
SMALL = {"n_agents": 100, "n_steps": 6}  # (one path: the fused Lanczos from N = 65)


def _same(a, b) -> bool:
    """Equal bit for bit: arrays (dtype, shape, bytes), dicts key by key, the rest by type and
    value."""
    if isinstance(a, tuple | list):
        return type(b) is type(a) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, dict):
        return type(b) is dict and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, np.ndarray):
        return (
            type(b) is np.ndarray
            and a.dtype == b.dtype
            and a.shape == b.shape
            and a.tobytes() == b.tobytes()
        )
    return type(a) is type(b) and (a == b or (a != a and b != b))


def _actions(rng: np.random.Generator, space: gym.spaces.Box, dtype) -> np.ndarray:
    return rng.uniform(-1.2, 1.2, space.shape).astype(dtype)


def gym_pair(**kwargs) -> tuple[gym.Env, gym.Env]:
    """(the compiled env, the numpy env) of `kwargs`."""
    fast = gym.make(ENV_ID, **kwargs)
    with switched_off("step"):
        slow = gym.make(ENV_ID, **kwargs)
    assert slow.unwrapped.plan.envelope == "numpy"
    return fast, slow


def run_gym(fast: gym.Env, slow: gym.Env, steps: int = 20, seed: int = 5) -> int:
    """Both envs through `steps` steps (reset on every episode end), equal bit for bit; returns
    the number of episode ends."""
    rng = np.random.default_rng(seed)
    ends = 0
    assert _same(fast.reset(seed=seed), slow.reset(seed=seed))
    for i in range(steps):
        a = _actions(rng, fast.action_space, (np.float32, np.float64)[i % 2])
        got, want = fast.step(a), slow.step(a.copy())
        assert _same(got, want), i
        assert _same(fast.unwrapped.positions, slow.unwrapped.positions)
        if got[2] or got[3]:
            ends += 1
            assert _same(fast.reset(seed=seed + i), slow.reset(seed=seed + i))
    return ends


@pytest.mark.parametrize("observation", ["absolute", "relative", "modes", "summary"])
@pytest.mark.parametrize("action_basis", ["agents", "common", "modes"])
def test_gymnasium_layouts_and_bases(observation, action_basis):
    fast, slow = gym_pair(observation=observation, action_basis=action_basis, **SMALL)
    compiled = action_basis != "modes"
    assert fast.unwrapped.plan.compiled_step == compiled
    assert run_gym(fast, slow) >= 2  # (truncated at the horizon, then reset)
    if compiled:
        envelope = "compiled-step" if observation == "absolute" else "compiled-step+numpy-tail"
        assert fast.unwrapped.plan.envelope == envelope
        assert not fast.unwrapped.plan_fallbacks


@pytest.mark.parametrize(
    "kwargs",
    [{"dim": 2}, {"n_paths": 3}, {"dim": 2, "n_paths": 4, "action_basis": "common"},
     {"integrator": "em"}, {"integrator": "erb"}, {"n_paths": 20, "n_agents": 100},
     {"target": 0.3, "gamma": 0.2}, {"integrator": "heun", "dim": 2}, {"integrator": "ee"},
     {"n_agents": 10}, {"n_agents": 60, "dim": 2, "action_basis": "common"},
     {"jacobian": "exact"}, {"phi_method": "eigh", "n_paths": 2}],
)  # fmt: skip
def test_gymnasium_shapes_and_schemes(kwargs):
    fast, slow = gym_pair(**{**SMALL, **kwargs})
    assert fast.unwrapped.plan.compiled_step
    run_gym(fast, slow)


@pytest.mark.parametrize(
    "kwargs", [{"action_basis": "modes"}, {"kernel": "nonsymmetric"}, {"n_agents": 2000}]
)
def test_where_the_plan_keeps_numpy(kwargs):
    """The "modes" basis, a kernel without the compiled pass, a matrix-free swarm: numpy."""
    env = gym.make(ENV_ID, **{**SMALL, **kwargs}).unwrapped
    assert env.plan.envelope == "numpy" and not env._compiled_step
    env.reset(seed=0)
    env.step(env.action_space.sample())
    assert not env.plan_fallbacks


def test_gymnasium_divergence_and_reset_options():
    fast, slow = gym_pair(n_agents=100, **DIVERGING)
    rng = np.random.default_rng(0)
    diverged = 0
    for episode in range(4):
        options = {"target": 0.1 * episode} if episode % 2 else None
        assert _same(fast.reset(seed=episode, options=options),
                     slow.reset(seed=episode, options=options))  # fmt: skip
        for _ in range(DIVERGING["n_steps"]):
            a = np.abs(_actions(rng, fast.action_space, np.float32)) + 0.5  # (clipped: 1)
            got, want = fast.step(a), slow.step(a)
            assert _same(got, want)
            if got[2] or got[3]:
                diverged += got[2]
                break
    assert diverged >= 1
    assert fast.unwrapped.plan_fallbacks == {"numpy-tail": diverged}


def test_other_actions_and_bad_ones_take_the_numpy_step():
    """Lists, float16 and int actions, the (N, d) shape and bad actions: the numpy step (its
    messages), counted as declined."""
    fast, slow = gym_pair(**SMALL)
    for env in (fast, slow):
        env.reset(seed=1)
    for a in ([0.1] * 100, np.full(100, 0.1, np.float16), np.zeros(100, int), np.zeros((100, 1))):
        assert _same(fast.step(a), slow.step(a))
    assert fast.unwrapped.plan_fallbacks["compiled-step-declined"] == 3
    bad = np.zeros(100, np.float32)
    bad[3] = np.nan
    state = fast.unwrapped.np_random.bit_generator.state
    with pytest.raises(ValueError, match="finite"):
        fast.step(bad)
    assert fast.unwrapped.np_random.bit_generator.state == state
    with pytest.raises(ValueError, match="shape"):
        fast.step(np.zeros(99, np.float32))


def test_strided_and_fortran_actions_take_the_compiled_step():
    """Actions that are views (every other entry of a longer array, a Fortran-ordered (N, d)):
    copied contiguous, the compiled step, the numpy step's bits."""
    fast, slow = gym_pair(**{**SMALL, "dim": 2})
    for env in (fast, slow):
        env.reset(seed=3)
    rng = np.random.default_rng(3)
    for _ in range(3):
        wide = rng.uniform(-1, 1, 400).astype(np.float32)
        fortran = np.asfortranarray(rng.uniform(-1, 1, (100, 2)))
        for a in (wide[::2], fortran):
            assert _same(fast.step(a), slow.step(np.array(a)))
    assert not fast.unwrapped.plan_fallbacks


def test_a_fused_step_that_gives_up_takes_the_general_step(monkeypatch):
    """A member's Lanczos that does not converge: the integrator's general step with the same
    draws, counted once ("fused-gave-up"), as the numpy step does."""
    original = loader.loaded("lanczos").frozen_advance
    monkeypatch.setattr(loader.loaded("lanczos"), "frozen_advance", lambda *a: original(*a) or 1)
    fast, slow = gym_pair(**SMALL)
    run_gym(fast, slow, steps=8)
    assert fast.unwrapped.plan_fallbacks == slow.unwrapped.plan_fallbacks
    assert fast.unwrapped.plan_fallbacks["fused-gave-up"] == 8


def test_a_fused_step_switched_off_after_the_env_was_made():
    """The path "fused" off after the envs were made: the plan keeps the fused step, which
    declines in every step; the integrator's general step with the same draws, counted once
    per step ("fused-declined") as the numpy step counts it."""
    fast, slow = gym_pair(**SMALL)
    with switched_off("fused"):
        run_gym(fast, slow, steps=8)
    assert fast.unwrapped.plan_fallbacks == slow.unwrapped.plan_fallbacks
    assert fast.unwrapped.plan_fallbacks["fused-declined"] == 8


def test_with_every_compiled_path_off():
    """Every compiled path switched off: the plan says numpy, and the steps are the compiled
    env's (N = 100, d = 1, one path: the compiled kernel pass and fused Lanczos give numpy's
    bits here; at d = 2 they differ by round-off, as before the compiled envelope)."""
    fast = gym.make(ENV_ID, **SMALL)
    with switched_off("step", "kernel", "lanczos", "fused", "noise"):
        slow = gym.make(ENV_ID, **SMALL)
        assert slow.unwrapped.plan.envelope == "numpy"
        run_gym(fast, slow)


def pz_pair(**kwargs):
    fast = swarm_v0.parallel_env(**kwargs)
    with switched_off("step"):
        slow = swarm_v0.parallel_env(**kwargs)
    assert slow.plan.envelope == "numpy"
    return fast, slow


def run_pz(fast, slow, steps: int = 16, seed: int = 2, push: bool = False) -> tuple[int, int]:
    rng = np.random.default_rng(seed)
    d = fast.config.params.dim
    ends = diverged = 0
    assert _same(fast.reset(seed=seed), slow.reset(seed=seed))
    for i in range(steps):
        acts = {a: rng.uniform(-1.2, 1.2, d).astype(np.float32) for a in fast.agents}
        if push:  # every agent to the right: beyond the threshold
            acts = {a: np.abs(v) + 0.5 for a, v in acts.items()}
        got, want = fast.step(acts), slow.step(acts)
        assert all(_same(g, w) for g, w in zip(got, want, strict=True)), i
        assert _same(fast.state(), slow.state()) and fast.agents == slow.agents
        assert _same(fast.last_control, slow.last_control)
        if not fast.agents:  # (every agent truncated or terminated)
            ends += 1
            diverged += any(got[2].values())
            assert _same(fast.reset(seed=seed + i), slow.reset(seed=seed + i))
    return ends, diverged


@pytest.mark.parametrize("observation", ["absolute", "relative", "swarm"])
@pytest.mark.parametrize("agent_reward", ["own", "team"])
@pytest.mark.parametrize("shape", [{}, {"dim": 2, "n_paths": 3}, {"n_agents": 10}])
def test_pettingzoo_layouts_and_rewards(observation, agent_reward, shape):
    fast, slow = pz_pair(observation=observation, agent_reward=agent_reward, **{**SMALL, **shape})
    assert fast.plan.envelope == "compiled-step+numpy-tail"
    assert run_pz(fast, slow)[0] >= 2
    assert not fast.plan_fallbacks


def test_pettingzoo_actions_in_any_order_and_of_mixed_types():
    """A dict keyed in another order than the agents', mixed float32/float64 and int actions
    and scalars for d = 1: the same stacked actions (or the numpy step), the same bits."""
    fast, slow = pz_pair(**SMALL)
    for env in (fast, slow):
        env.reset(seed=7)
    rng = np.random.default_rng(7)
    agents = fast.possible_agents
    choices = (
        lambda k: rng.uniform(-1, 1, 1).astype(np.float32),
        lambda k: rng.uniform(-1, 1, 1),
        lambda k: np.float32(rng.uniform(-1, 1)),
        lambda k: np.array([k % 3 - 1]),
    )
    for i, kind in enumerate((0, 1, 2, 3, 4)):
        if kind < 4:
            acts = {a: choices[kind](k) for k, a in reversed(list(enumerate(agents)))}
        else:  # mixed dtypes: stacking promotes to float64
            acts = {a: choices[k % 2](k) for k, a in enumerate(agents)}
        assert all(_same(g, w) for g, w in zip(fast.step(acts), slow.step(acts), strict=True)), i


def test_pettingzoo_divergence():
    fast, slow = pz_pair(n_agents=100, **DIVERGING)
    assert run_pz(fast, slow, steps=30, push=True)[1] >= 1


_TRAJECTORY = """
import hashlib, pickle
import gymnasium as gym, numpy as np
import agent_envs
from agent_envs import swarm_v0

def trajectory(kwargs):
    env = gym.make("agent_envs/Swarm-v0", **kwargs)
    par = swarm_v0.parallel_env(**kwargs)
    rng = np.random.default_rng(1)
    out = [env.reset(seed=4), par.reset(seed=4), env.unwrapped.plan.envelope, par.plan.envelope]
    for _ in range(kwargs["n_steps"] + 1):
        a = rng.uniform(-1.2, 1.2, env.action_space.shape).astype(np.float32)
        out.append(env.step(a) if not env.unwrapped.episode.done else env.reset(seed=5))
        acts = dict(zip(par.possible_agents, a.reshape(len(par.possible_agents), -1)))
        out.append(par.step(acts) if par.agents else par.reset(seed=5))
    return out
"""


def test_numba_off_in_a_fresh_process_gives_the_same_bits():
    """AGENT_ENVS_NUMBA=0 (no compiled path, numba never imported): the Gymnasium and the
    PettingZoo env's plans say numpy, and their outputs over an episode and a reset are those
    of envs made and stepped here with every compiled path switched off (the compiled kernel
    pass and Lanczos round differently from numpy's at d = 2: numba on and off differ by
    round-off, as they did before the compiled envelope; the envelope itself changes nothing,
    `test_with_every_compiled_path_off`)."""
    import pickle
    import subprocess
    import sys

    kwargs = {"n_agents": 100, "n_steps": 4, "dim": 2, "n_paths": 2}
    code = _TRAJECTORY + f"import sys; sys.stdout.buffer.write(pickle.dumps(trajectory({kwargs})))"
    env = {"AGENT_ENVS_NUMBA": "0", "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    slow = pickle.loads(done.stdout)
    namespace: dict = {}
    exec(_TRAJECTORY, namespace)  # (the same function in this process)
    assert namespace["trajectory"](kwargs)[2:4] == ["compiled-step", "compiled-step+numpy-tail"]
    with switched_off("step", "kernel", "lanczos", "fused", "noise"):
        here = namespace["trajectory"](kwargs)
    assert slow[2:4] == here[2:4] == ["numpy", "numpy"]
    assert _same(here, slow)


@pytest.mark.parametrize(
    "shape", [(1, 1, 100, 1), (2, 20, 100, 1), (1, 3, 129, 2), (1, 2, 20, 8), (1, 1, 3, 16)]
)
def test_the_per_agent_calls_equal_numpy_bit_for_bit(shape):
    """`compiled_agents.agents_same_as_numpy` (part of the path's load check) on more shapes:
    d below and above 8, N beyond numpy's pairwise block, one and many paths."""
    assert agents_same_as_numpy(loader.loaded("step"), shapes=(shape,))


class _OffByOneUlp:
    """The compiled module with the per-agent costs or rows nudged by one ulp: the check sees
    it."""

    def __init__(self, what: str) -> None:
        self.module, self.what = loader.loaded("step"), what

    def agent_costs(self, *args):
        self.module.agent_costs(*args)
        if self.what == "costs":
            args[-1].flat[-1] = np.nextafter(args[-1].flat[-1], np.inf)

    def agent_rows(self, *args):
        self.module.agent_rows(*args)
        if self.what == "rows":
            args[-1].flat[0] = np.nextafter(args[-1].flat[0], np.float32(np.inf))


@pytest.mark.parametrize("what", ["costs", "rows"])
def test_the_per_agent_check_sees_one_ulp(what):
    assert not agents_same_as_numpy(_OffByOneUlp(what))


def test_the_combined_calls_equal_the_separate_ones():
    """`compiled_agents.combined_same_as_separate` (part of the path's load check): the
    PettingZoo step's `prologue_agents` and `epilogue_agents` give the separate calls' bits."""
    assert combined_same_as_separate(loader.loaded("step"))


class _CombinedOffByOneUlp:
    """The compiled module with the combined calls' per-agent costs or rows nudged by one ulp."""

    def __init__(self, what: str) -> None:
        self.module, self.what = loader.loaded("step"), what

    def __getattr__(self, name):
        return getattr(self.module, name)

    def prologue_agents(self, *args):
        found = self.module.prologue_agents(*args)
        if self.what == "costs":
            args[-1].flat[-1] = np.nextafter(args[-1].flat[-1], np.inf)
        return found

    def epilogue_agents(self, *args):
        self.module.epilogue_agents(*args)
        if self.what == "rows":
            args[-1].flat[0] = np.nextafter(args[-1].flat[0], np.float32(np.inf))


@pytest.mark.parametrize("what", ["costs", "rows"])
def test_the_combined_check_sees_one_ulp(what):
    assert not combined_same_as_separate(_CombinedOffByOneUlp(what))
