"""The step plan (`agent_envs.envs.step_plan.StepPlan`): which code an env step runs, resolved
once where the env is made, shown on every env (`plan`, `repr`), read by the hot code, and the
mid-step fallbacks counted in `plan_fallbacks`.

The plan must describe the paths the steps take (the native vector env's blocks and compiled
step are read from it) and change no number: the single env's integrator is built with the
plan's resolved phi strategy instead of "auto", bit for bit the same states; the compiled paths
switched off give the same bits where they did before.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager

import gymnasium as gym
import numpy as np
import pytest
from test_vector_env import DIVERGING, native, run_side_by_side, sync

import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)
from agent_envs import native as native_paths
from agent_envs import swarm_v0
from agent_envs.envs import ENV_ID, SwarmVectorEnv
from agent_envs.envs.step_plan import ENVELOPES, FALLBACKS, StepPlan
from agent_envs.integrators import make_integrator
from agent_envs.native import loader

KERNEL = "compiled" if native_paths.available("kernel") else "numpy"
LANCZOS = "compiled-lanczos" if native_paths.available("lanczos") else "lanczos"
FUSED = "fused-lanczos" if native_paths.available("fused") else LANCZOS
COMPILED_STEP = native_paths.available("step") and FUSED == "fused-lanczos"


@contextmanager
def switched_off(*names: str) -> Iterator[None]:
    """The compiled paths `names` off inside; every path as it was after (not loaded again)."""
    saved = dict(loader._loaded)
    for name in names:
        native_paths.use(name, False)
    try:
        yield
    finally:
        loader._loaded.update(saved)


def make(**kwargs) -> gym.Env:
    return gym.make(ENV_ID, **kwargs)


def step_all(env: gym.Env, steps: int, seed: int = 3) -> list:
    """Observations, rewards and positions of `steps` steps from a seeded reset."""
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(0)
    out = [obs]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(
            rng.uniform(-0.5, 0.5, env.action_space.shape).astype(np.float32)
        )
        out += [obs, reward, info["positions"]]
        if terminated or truncated:
            break
    return out


def assert_same_bits(a: list, b: list) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


# ------------------------------------------------------------------------- the plans
@pytest.mark.parametrize(
    ("kwargs", "want"),
    [
        ({"integrator": "em", "n_agents": 20}, {"integrator": "em", "jacobian": "none",
          "phi": "none", "kernel_pass": KERNEL, "linear_operator": "dense"}),
        # N = 10: below the Lanczos threshold, "auto" is expm
        ({"n_agents": 10}, {"integrator": "serb", "jacobian": "frozen", "phi_method": "expm",
          "phi": "expm", "kernel_pass": KERNEL, "linear_operator": "dense"}),
        ({"n_agents": 100}, {"phi_method": "krylov", "phi": FUSED, "kernel_pass": KERNEL}),
        ({"n_agents": 100, "phi_method": "eigh"}, {"phi_method": "eigh", "phi": "eigh"}),
        ({"n_agents": 100, "jacobian": "exact"}, {"jacobian": "exact", "phi": "lanczos"}),
        ({"n_agents": 130, "kernel": "nonsymmetric"}, {"phi": "arnoldi", "kernel_pass": "numpy"}),
        # N = 2000 (d = 1): matrix-free, the grid sum, the Krylov action on the operator
        ({"n_agents": 2000}, {"linear_operator": "matrix_free", "kernel_pass": "grid",
          "phi_method": "krylov", "phi": "krylov-matrix-free"}),
        ({"n_agents": 2000, "dim": 2}, {"linear_operator": "matrix_free",
          "kernel_pass": "chunked", "phi": "krylov-matrix-free"}),
    ],
)  # fmt: skip
def test_the_single_envs_plans(kwargs, want):
    """The Gymnasium and the PettingZoo env resolve the same plan (their `env` and envelope
    aside: the PettingZoo env builds its per-agent outputs by numpy), and their integrator is
    built with its `phi_method`. Their envelope is the compiled step wherever the compiled
    kernel pass serves the dense workspace (`compiled_episode.compiled_episode_step`)."""
    plan = make(**kwargs).unwrapped.plan
    assert isinstance(plan, StepPlan)
    assert {key: getattr(plan, key) for key in want} == want
    compiled = (
        native_paths.available("step")
        and plan.kernel_pass == "compiled"
        and plan.linear_operator == "dense"
    )
    assert (plan.env, plan.envelope, plan.num_envs, plan.blocks, plan.n_paths) == (
        "gymnasium", "compiled-step" if compiled else "numpy", 1, 1, 1
    )  # fmt: skip
    assert (plan.backend, plan.device, plan.threads) == ("numpy", "cpu", 1)
    parallel = swarm_v0.parallel_env(**kwargs)
    envelope = "compiled-step+numpy-tail" if compiled else "numpy"
    assert parallel.plan == dataclasses.replace(plan, env="pettingzoo", envelope=envelope)
    integrator = parallel.episode.integrator
    assert getattr(integrator, "phi_method", plan.phi_method) == plan.phi_method


def test_n_paths_reaches_the_integrator_through_the_plan():
    """N = 60: "auto" is expm for one path and the Lanczos for 20 (`auto_phi_method`); the
    env's integrator is built with the plan's choice."""
    for n_paths, method in ((1, "expm"), (20, "krylov")):
        env = make(n_agents=60, n_paths=n_paths).unwrapped
        assert env.plan.n_paths == n_paths and env.plan.phi_method == method
        assert env.episode.integrator.phi_method == method
    assert make(n_agents=60, n_paths=20).unwrapped.plan.phi == FUSED


def test_every_env_resolves_one_plan_for_its_model_and_integrator(monkeypatch):
    """n_paths goes from the env's kwargs to its integrator through one plan: each env, made
    once, resolves its plan once (`step_plan.planned_step`), with the model it steps with,
    and its integrator takes the plan's strategy."""
    from agent_envs.envs import step_plan

    seen = []
    original = step_plan.resolve_step_plan

    def counted(config, model, **options):
        plan = original(config, model, **options)
        seen.append((options.get("env"), model, plan))
        return plan

    monkeypatch.setattr(step_plan, "resolve_step_plan", counted)
    kwargs = {"n_agents": 60, "n_paths": 20}
    envs = [make(**kwargs).unwrapped, swarm_v0.parallel_env(**kwargs), SwarmVectorEnv(2, **kwargs)]
    assert [env for env, _, _ in seen] == ["gymnasium", "pettingzoo", "vector"]
    for env, (_, model, plan) in zip(envs, seen, strict=True):
        assert env.model is model and env.plan is plan and env.phi_method == plan.phi_method
        assert plan.n_paths == 20 and plan.phi_method == "krylov"


def test_the_vector_envs_plans():
    env = SwarmVectorEnv(4, n_agents=100)
    plan = env.plan
    assert (plan.env, plan.num_envs, plan.phi, plan.kernel_pass) == ("vector", 4, FUSED, KERNEL)
    assert plan.envelope == ("compiled-step" if COMPILED_STEP else "numpy")
    assert plan.compiled_step == COMPILED_STEP and plan.fused == (FUSED == "fused-lanczos")
    assert env.integrator.phi_method == env.phi_method == plan.phi_method == "krylov"
    # the blocks the step goes through are the plan's
    assert plan.blocks == len(env._blocks)
    assert plan.blocks * plan.envs_per_block >= plan.num_envs
    with switched_off("step"):
        numpy_step = SwarmVectorEnv(4, n_agents=100).plan
    assert numpy_step == dataclasses.replace(plan, envelope="numpy")
    em = SwarmVectorEnv(3, n_agents=12, integrator="em").plan
    assert (em.phi, em.envelope) == ("none", "compiled-step" if native_paths.available("step")
                                     else "numpy")  # fmt: skip
    relative = SwarmVectorEnv(2, n_agents=100, observation="relative").plan
    assert relative.envelope == ("compiled-step+numpy-tail" if COMPILED_STEP else "numpy")
    assert SwarmVectorEnv(2, n_agents=100, action_basis="modes").plan.envelope == "numpy"
    assert SwarmVectorEnv(2, n_agents=10).plan.envelope == "numpy"  # (expm: no fused step)
    with switched_off("kernel", "lanczos"):  # numpy passes: blocks of BLOCK_BYTES
        blocks = SwarmVectorEnv(64, n_agents=100, n_paths=20)
    assert blocks.plan.phi == "lanczos" and blocks.plan.kernel_pass == "numpy"
    assert blocks.plan.envelope == "numpy" and blocks.plan.blocks == len(blocks._blocks) > 1


def test_the_torch_vector_envs_plan():
    pytest.importorskip("torch")
    plan = SwarmVectorEnv(2, n_agents=100, backend="torch").plan
    assert (plan.backend, plan.device, plan.kernel_pass, plan.phi) == (
        "torch", "cpu", "torch", "lanczos"
    )  # fmt: skip
    assert (plan.envelope, plan.blocks) == ("numpy", 1)


def test_the_plan_is_frozen_and_described_in_one_line():
    plan = make(n_agents=100).unwrapped.plan
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.phi = "expm"  # type: ignore[misc]
    assert hash(plan) == hash(dataclasses.replace(plan))
    line = plan.describe()
    assert "\n" not in line and line.startswith("serb/frozen ")
    assert f"phi={plan.phi}" in line and f"kernel={plan.kernel_pass}" in line
    assert plan.as_dict()["phi"] == plan.phi
    assert plan.envelope in ENVELOPES
    vector = SwarmVectorEnv(3, n_agents=20, integrator="em").plan.describe()
    assert vector.startswith("em phi=none ") and " envs=3 blocks=" in vector


def test_every_env_shows_its_plan_in_its_repr():
    env = make(n_agents=100)
    line = env.unwrapped.plan.describe()
    assert repr(env.unwrapped) == f"<SwarmEnv<{ENV_ID}> {line}>"
    assert "serb/frozen" in repr(env.unwrapped) and f"phi={FUSED}" in repr(env.unwrapped)
    # Gymnasium's str, which its wrappers print, is unchanged
    assert str(env.unwrapped) == f"<SwarmEnv<{ENV_ID}>>"
    assert repr(env).endswith(f"<SwarmEnv<{ENV_ID}>>>>>") and line not in repr(env)
    parallel = swarm_v0.parallel_env(n_agents=10)
    assert repr(parallel) == f"<SwarmParallelEnv<swarm_v0> {parallel.plan.describe()}>"
    assert str(parallel) == "swarm_v0"
    vector = native(2, n_agents=10)
    assert repr(vector.unwrapped) == (
        f"SwarmVectorEnv({ENV_ID}, num_envs=2, plan: {vector.unwrapped.plan.describe()})"
    )


# ------------------------------------------------------------------ the same numbers
@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_agents": 60, "n_paths": 1},  # expm
        {"n_agents": 60, "n_paths": 3},  # the Lanczos (fused where numba serves)
        {"n_agents": 30, "dim": 2, "jacobian": "exact", "epsilon": 0.5},
        {"n_agents": 100, "kernel": "nonsymmetric", "n_paths": 2},  # Arnoldi
        {"n_agents": 12, "linear_operator": "matrix_free"},  # the operator: "krylov"
    ],
)
def test_the_resolved_phi_method_gives_the_bits_of_auto(kwargs):
    """The single env's integrator built with the plan's phi strategy against one built with
    "auto" (what it was before the plan): the same states bit for bit."""
    planned, auto = make(n_steps=8, **kwargs), make(n_steps=8, **kwargs)
    config = auto.unwrapped.config
    auto.unwrapped.episode.integrator = make_integrator(
        config.integrator, jacobian=config.jacobian, phi_method="auto"
    )
    assert_same_bits(step_all(planned, 8), step_all(auto, 8))


@pytest.mark.skipif(FUSED != "fused-lanczos", reason="the fused step needs numba")
def test_the_steps_take_the_plans_path_and_the_same_bits(monkeypatch):
    """An env made with the fused step off (its plan says compiled-lanczos) takes no fused
    step, though the path is on again when it steps; against the fused env, bit for bit, as
    the fused step promises. Switched off after it was made, the fused env takes the general
    step (the same bits again), counted as "fused-declined"."""
    with switched_off("fused"):
        general = make(n_agents=100, n_paths=2, n_steps=6)
    fused = make(n_agents=100, n_paths=2, n_steps=6)
    assert general.unwrapped.plan.phi == "compiled-lanczos"
    assert fused.unwrapped.plan.phi == "fused-lanczos"
    lanczos = loader.loaded("lanczos")
    calls: list[int] = []
    original = lanczos.frozen_advance
    monkeypatch.setattr(lanczos, "frozen_advance", lambda *a: calls.append(1) or original(*a))
    want = step_all(general, 6)
    assert not calls
    assert_same_bits(step_all(fused, 6), want)
    assert len(calls) == 6 and fused.unwrapped.plan_fallbacks == {}
    calls.clear()
    with switched_off("fused"):
        assert_same_bits(step_all(fused, 6), want)
    assert not calls and fused.unwrapped.plan_fallbacks == {"fused-declined": 6}


def test_the_vector_env_on_a_forced_matrix_free_operator_steps():
    """linear_operator="matrix_free" at N = 12: the single env's "auto" ran the Krylov action
    on the operator, while the vector env fixed "expm" for it and raised in its first step;
    through the plan both resolve "krylov". (On the matrix-free operator the vector env follows
    SyncVectorEnv to round-off, not bit for bit, as it did at N = 500 before the plan.)"""
    kwargs = {**DIVERGING, "n_agents": 12, "n_steps": 4, "linear_operator": "matrix_free"}
    assert SwarmVectorEnv(2, **kwargs).plan.phi_method == "krylov"
    run_side_by_side(2, 6, exact=False, **kwargs)


# ------------------------------------------------------------------------- fallbacks
def _unconverged(monkeypatch) -> None:
    """Every fused step reports a member whose Lanczos did not converge."""
    module = loader.loaded("lanczos")
    original = module.frozen_advance

    def unconverged(*args):
        original(*args)
        return 1

    monkeypatch.setattr(module, "frozen_advance", unconverged)


@pytest.mark.skipif(FUSED != "fused-lanczos", reason="the fused step needs numba")
def test_a_fused_step_that_gives_up_is_counted_and_changes_no_bit(monkeypatch):
    with switched_off("fused"):
        general = make(n_agents=100, n_steps=5)
    env = make(n_agents=100, n_steps=5)
    assert env.unwrapped.plan_fallbacks == {}
    _unconverged(monkeypatch)
    assert_same_bits(step_all(env, 5), step_all(general, 5))
    assert env.unwrapped.plan_fallbacks["fused-gave-up"] == 5
    assert general.unwrapped.plan_fallbacks == {}
    venv = native(3, n_agents=100, n_steps=5)
    venv.reset(seed=0)
    venv.step(np.zeros((3, 100), dtype=np.float32))
    # (the compiled step's fused call gave up, and the numpy advance's retry too)
    assert venv.unwrapped.plan_fallbacks["fused-gave-up"] == 2
    assert set(venv.unwrapped.plan_fallbacks) <= set(FALLBACKS)


@pytest.mark.skipif(not COMPILED_STEP, reason="the compiled step needs numba")
def test_the_compiled_steps_fallbacks_are_counted():
    """Actions the compiled step does not take, a diverging env, and the fused step switched
    off after the env was made: counted, and the env still equals SyncVectorEnv."""
    kwargs = {**DIVERGING, "n_agents": 100, "n_steps": 6}
    venv, senv = native(3, **kwargs), sync(3, **kwargs)
    fallbacks = venv.unwrapped.plan_fallbacks
    for env in (venv, senv):
        env.reset(seed=4)
    assert fallbacks == {}
    push = np.zeros((3, 100))
    push[1] = 1.0  # env 1 diverges within the episode
    for k in range(6):
        a = push.tolist() if k == 0 else push  # a list: not the compiled step's
        got, want = venv.step(a), senv.step(a)
        for g, w in zip(got[:4], want[:4], strict=True):
            np.testing.assert_array_equal(g, w)
    assert fallbacks["compiled-step-declined"] == 1
    assert fallbacks["numpy-tail"] >= 1
    with switched_off("fused"):
        got, want = venv.step(push), senv.step(push)
    for g, w in zip(got[:4], want[:4], strict=True):
        np.testing.assert_array_equal(g, w)
    assert fallbacks["fused-declined"] == 1
    assert set(fallbacks) <= set(FALLBACKS)


# ---------------------------------------------------------------------- run metadata
def test_a_runs_env_description_records_the_plan():
    pytest.importorskip("stable_baselines3")
    from agent_envs.training.learners.environments import env_description, training_step_plan
    from agent_envs.training.learners.native_vec_env import NativeVecEnv

    kwargs = {"n_agents": 10, "n_steps": 5}
    description = env_description(ENV_ID, kwargs)
    assert description["step_plan"] == make(**kwargs).unwrapped.plan.describe()
    assert description["step_plan"].startswith("serb/frozen phi=expm ")
    venv = NativeVecEnv(2, kwargs)
    assert training_step_plan(venv) == SwarmVectorEnv(2, **kwargs).plan.describe()
    venv.close()
    assert training_step_plan(object()) is None
