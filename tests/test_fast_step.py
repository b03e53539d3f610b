"""The native vector env's compiled prologue and epilogue (`agent_envs.native.step`).

They replace about 30 numpy calls of the native env's step (controls, running costs,
right-hand sides, divergence flags, path means, observation) and must give their values bit
for bit, so that the native env still equals `SyncVectorEnv` over the single env, which keeps
the numpy calls. `fast_step.same_as_numpy` is the check run when the module loads; here it
runs on more shapes, is shown to fail on values one ulp off, and the env is run against
SyncVectorEnv through the compiled step, its fallbacks and the numpy step.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from test_vector_env import DIVERGING, native, run_side_by_side

from agent_envs.envs import fast_step
from agent_envs.native import loader

pytestmark = pytest.mark.skipif(
    not fast_step.load_compiled_step(), reason="the compiled step needs numba"
)


@contextmanager
def numpy_step() -> Iterator[None]:
    """Native envs made inside take the numpy step: the path "step" is off while they are made
    (their `plan.envelope` is "numpy"), and back as it was after."""
    before = loader.use("step", False)
    try:
        yield
    finally:
        loader.use("step", before)


@pytest.mark.parametrize(
    "shape",
    [(3, 1, 100, 1), (2, 20, 100, 1), (1, 8, 7, 2), (2, 2, 8, 1), (1, 1, 129, 1),
     (1, 3, 257, 2), (1, 1, 1000, 1), (2, 5, 33, 7), (1, 2, 20, 8), (1, 1, 3, 16)],
)  # fmt: skip
def test_prologue_and_epilogue_equal_numpy_bit_for_bit(shape):
    """N below, at and beyond numpy's pairwise blocks (8, 128, two and three levels of
    halving), d below and above 8 (a pairwise sum over the coordinates), one and many paths."""
    assert fast_step.same_as_numpy(fast_step.compiled_step(), shapes=(shape,))


class _OffByOneUlp:
    """The compiled module with one output nudged by one ulp (`what`): the check must see it."""

    def __init__(self, what: str) -> None:
        self.module, self.what = fast_step.compiled_step(), what

    def prologue(self, actions, max_control, x, drift, targets, gamma, controls, costs, rhs):
        ok = self.module.prologue(actions, max_control, x, drift, targets, gamma, controls,
                                  costs, rhs)  # fmt: skip
        target = {"costs": costs, "controls": controls, "rhs": rhs}.get(self.what)
        if ok and target is not None:
            target.flat[-1] = np.nextafter(target.flat[-1], np.inf)
        return ok

    def epilogue(self, *args):
        self.module.epilogue(*args)
        means_x, means_f, obs = args[8], args[9], args[10]
        target = {"positions": means_x, "drift": means_f}.get(self.what)
        if target is not None:
            target.flat[0] = np.nextafter(target.flat[0], np.inf)
        if self.what == "observation":
            obs.flat[0] = np.nextafter(obs.flat[0], np.float32(np.inf))
        if self.what == "flags":
            args[11][0] = not args[11][0]


@pytest.mark.parametrize("what", ["costs", "controls", "rhs", "positions", "drift", "observation"])
def test_the_load_check_sees_one_ulp(what):
    assert not fast_step.same_as_numpy(_OffByOneUlp(what))


def test_a_module_that_differs_is_not_used(monkeypatch):
    """load_compiled_step answers False, with a warning, where the check fails; the env then
    takes the numpy step."""
    off, real = _OffByOneUlp("costs"), loader.import_compiled

    def importing(name):  # (the other compiled modules load as they are)
        return off if name == "agent_envs.native.step" else real(name)

    monkeypatch.setitem(loader._loaded, "step", None)
    monkeypatch.setattr(loader, "import_compiled", importing)
    with pytest.warns(RuntimeWarning, match="differs from numpy"):
        assert not fast_step.load_compiled_step()
    assert native(2, n_agents=20, integrator="em").unwrapped.plan.envelope == "numpy"


def _count_calls(monkeypatch) -> dict[str, int]:
    calls = {"prologue": 0, "epilogue": 0}
    module = fast_step.compiled_step()
    for name in calls:
        original = getattr(module, name)

        def counted(*args, _name=name, _original=original):
            calls[_name] += 1
            return _original(*args)

        monkeypatch.setattr(module, name, counted)
    return calls


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_agents": 100, "n_steps": 6},  # SERB, its fused Lanczos step
        {"n_agents": 30, "n_steps": 6, "dim": 2, "n_paths": 3, "phi_method": "krylov"},
        {"n_agents": 100, "n_steps": 6, "integrator": "erb", "target": [-0.5]},
        {"n_agents": 10, "integrator": "em", "epsilon": 0.5, "n_paths": 2},
        {"n_agents": 100, "n_steps": 6, "observation": "relative"},
        {"n_agents": 20, "n_steps": 6, "dim": 9, "integrator": "em", "epsilon": 0.5},
        {"n_agents": 100, "n_steps": 6, "action_basis": "common", "observation": "summary"},
        {"n_agents": 30, "n_steps": 6, "dim": 2, "n_paths": 3, "phi_method": "krylov",
         "action_basis": "common"},
    ],
)  # fmt: skip
def test_native_env_through_the_compiled_step_equals_sync(monkeypatch, kwargs):
    """The native env against SyncVectorEnv with the compiled step (counted), through
    divergence (env 1 is pushed out of the threshold; its step falls back to the numpy tail)
    and autoresets (the numpy step), over three episodes."""
    calls = _count_calls(monkeypatch)
    kwargs = {**DIVERGING, **kwargs}
    steps = 3 * kwargs["n_steps"] + 2
    terminated, truncated = run_side_by_side(4, steps, **kwargs)
    assert terminated >= 2 and truncated >= 6
    # (a step after an episode's end autoresets: the numpy step; with d = 9 and EM most
    # episodes end early, so at least one episode's worth of steps)
    assert calls["prologue"] >= kwargs["n_steps"]
    assert calls["epilogue"] == calls["prologue"]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_agents": 100, "n_steps": 6, "autoreset_mode": "SameStep"},
        {"n_agents": 30, "n_steps": 6, "dim": 2, "n_paths": 3, "phi_method": "krylov",
         "autoreset_mode": "SameStep"},
        {"n_agents": 131, "n_steps": 6, "integrator": "em", "epsilon": 0.5, "dim": 2},
    ],
)  # fmt: skip
def test_same_step_autoreset_and_large_n_through_the_compiled_step(monkeypatch, kwargs):
    """SAME_STEP (the compiled step hands its arrays to the numpy tail) and N > 128 (the
    pairwise sums' second level) against SyncVectorEnv in that mode."""
    from gymnasium.vector import AutoresetMode

    calls = _count_calls(monkeypatch)
    kwargs = {**DIVERGING, **kwargs}
    if "autoreset_mode" in kwargs:  # (native and SyncVectorEnv both take it)
        kwargs["autoreset_mode"] = AutoresetMode(kwargs["autoreset_mode"])
    run_side_by_side(3, 2 * kwargs["n_steps"] + 1, seed=2, **kwargs)
    assert calls["prologue"] >= kwargs["n_steps"]


def test_threads_partial_resets_and_strided_actions_through_the_compiled_step(monkeypatch):
    """num_threads = 2 (where numba allows two), a reset of some envs mid-episode
    (`reset_mask`) and actions of other memory layouts (Fortran order, a strided view, a
    broadcast row, float32 (B, N, d)): the compiled step, the same bits as the numpy step."""
    from agent_envs.dynamics.laplacian import max_compiled_threads

    calls = _count_calls(monkeypatch)
    threads = 2 if max_compiled_threads() >= 2 else 1
    kwargs = {"n_agents": 100, "n_steps": 8, "n_paths": 2}
    fast = native(4, num_threads=threads, **kwargs)
    with numpy_step():
        slow = native(4, **kwargs)
    assert fast.unwrapped.plan.envelope == "compiled-step"
    assert slow.unwrapped.plan.envelope == "numpy"
    fast.reset(seed=9)
    slow.reset(seed=9)
    rng = np.random.default_rng(3)
    base = rng.uniform(-1.2, 1.2, (4, 200))
    layouts = [
        np.asfortranarray(base[:, :100]),
        base[:, ::2],
        np.broadcast_to(base[0, :100], (4, 100)),
        base[:, :100].astype(np.float32).reshape(4, 100, 1),
    ]
    for step in range(12):
        if step == 5:
            mask = np.array([True, False, True, False])
            for env in (fast, slow):
                env.reset(options={"reset_mask": mask})
        a = layouts[step % len(layouts)]
        got, want = fast.step(a), slow.step(a)
        for g, w in zip(got[:4], want[:4], strict=True):
            np.testing.assert_array_equal(g, w)
        for key in ("positions", "control", "running_cost", "time"):
            np.testing.assert_array_equal(got[4][key], want[4][key])
    assert calls["prologue"] >= 8


def test_an_env_whose_phi_action_is_not_the_lanczos_takes_the_numpy_step(monkeypatch):
    """SERB at N = 12 ("auto": expm) or with phi_method="eigh" never has the fused step: the
    compiled step is off from the start, not tried and dropped."""
    calls = _count_calls(monkeypatch)
    for kwargs in ({"n_agents": 12}, {"n_agents": 100, "phi_method": "eigh"}):
        env = native(2, n_steps=4, **kwargs)
        assert env.unwrapped.plan.envelope == "numpy"
        assert env.unwrapped.plan.phi == ("expm" if "phi_method" not in kwargs else "eigh")
        env.reset(seed=0)
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    assert calls["prologue"] == 0
    fused = native(2, n_agents=100).unwrapped.plan
    assert fused.envelope == "compiled-step" and fused.phi == "fused-lanczos"
    em = native(2, n_agents=12, integrator="em").unwrapped.plan
    assert em.envelope == "compiled-step" and em.integrator == "em" and em.phi == "none"
    assert native(2, n_agents=100, action_basis="modes").unwrapped.plan.envelope == "numpy"


def test_compiled_and_numpy_steps_give_the_same_bits(monkeypatch):
    """Two native envs from one seed, one with the compiled step switched off."""
    calls = _count_calls(monkeypatch)
    kwargs = {"n_agents": 100, "n_steps": 8, "n_paths": 2}
    fast = native(3, **kwargs)
    with numpy_step():
        slow = native(3, **kwargs)
    assert fast.unwrapped.plan.envelope == "compiled-step"
    assert slow.unwrapped.plan.envelope == "numpy"
    fast.reset(seed=5)
    slow.reset(seed=5)
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.uniform(-1.5, 1.5, (3, 100))  # float64, beyond the action box: clipped
        got, want = fast.step(a), slow.step(a)
        for g, w in zip(got[:4], want[:4], strict=True):
            assert g.dtype == w.dtype
            np.testing.assert_array_equal(g, w)
        for key in ("positions", "control", "running_cost", "time"):
            np.testing.assert_array_equal(got[4][key], want[4][key])
    assert calls["prologue"] >= 17


def test_non_finite_actions_raise_before_any_draw():
    """The compiled step checks the actions before it draws: the numpy step's ValueError, and
    every env's generator where it was."""
    env = native(3, n_agents=100, n_steps=5)
    env.reset(seed=0)
    env.step(np.zeros((3, 100), dtype=np.float32))
    states = [rng.bit_generator.state for rng in env.unwrapped.np_randoms]
    a = np.zeros((3, 100), dtype=np.float32)
    a[2, 7] = np.inf
    with pytest.raises(ValueError, match="actions must be finite"):
        env.step(a)
    assert [rng.bit_generator.state for rng in env.unwrapped.np_randoms] == states


def test_a_fused_step_that_gives_up_takes_the_numpy_advance(monkeypatch):
    """Where a member's Lanczos does not converge, the compiled step takes the numpy step's
    `_advance` with the same draws (the single envs give up too here: the same bits)."""
    calls = _count_calls(monkeypatch)
    original = loader.loaded("lanczos").frozen_advance

    def unconverged(*args):
        original(*args)
        return 1  # the number of members that did not converge

    monkeypatch.setattr(loader.loaded("lanczos"), "frozen_advance", unconverged)
    kwargs = {**DIVERGING, "n_agents": 100, "n_steps": 5}
    run_side_by_side(3, 8, **kwargs)
    assert calls["prologue"] >= 5 and calls["epilogue"] == 0


def test_other_actions_take_the_numpy_step(monkeypatch):
    """Lists, float16 and integer actions are not the compiled step's: the numpy step runs
    (and accepts them as before)."""
    calls = _count_calls(monkeypatch)
    env = native(2, n_agents=100, n_steps=5)
    env.reset(seed=0)
    for a in ([[0.1] * 100] * 2, np.full((2, 100), 0.1, np.float16), np.zeros((2, 100), int)):
        env.step(a)
    assert calls["prologue"] == 0
    env.step(np.zeros((2, 100, 1)))  # (B, N, d) float64
    assert calls["prologue"] == 1


@pytest.mark.slow
def test_the_one_call_experiment_still_runs_and_matches_the_env_bit_for_bit():
    """benchmarks/one_call_step.py backs a figure in docs/benchmarks.md ("Where the two ratio
    targets end"): the native step composed into one compiled call gives the env's outputs bit
    for bit (it exits non-zero otherwise, or when its steps did not take the one call). It
    reaches into the env's private state, so a refactor that breaks it should show here."""
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "one_call_step.py"
    done = subprocess.run(
        [sys.executable, str(script), "--envs", "8", "--rounds", "1"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr[-2000:] + done.stdout[-2000:]
    assert "bit for bit over 120 steps, 118 of them through the one call" in done.stdout
    assert "current / one call" in done.stdout
