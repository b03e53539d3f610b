"""The one switch of the compiled paths (`agent_envs.native`): the environment variable turns
every path off, `use(name, on)` one of them, an unknown name is refused; the switches of
before (`use_compiled`, `use_compiled_kernel`, `use_compiled_noise`, `use_fused_step`) are
the same switch."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import agent_envs  # noqa: F401  (registers the env ids and the owners' checks)
from agent_envs import native
from agent_envs.dynamics import laplacian
from agent_envs.integrators import exponential, phi_functions
from agent_envs.native import loader

NAMES = ("kernel", "lanczos", "fused", "noise", "step")


@pytest.fixture
def restored():
    """The paths' states as they were before the test (a path turned back on is not loaded and
    checked again)."""
    saved = dict(loader._loaded)
    yield
    loader._loaded.update(saved)


def test_the_paths_are_named():
    assert tuple(native.PATHS) == NAMES
    assert set(native.status()) == set(NAMES)
    for path in native.PATHS.values():
        assert path.module.startswith("agent_envs.native.")


def test_environment_variable_turns_every_path_off_and_the_envs_still_step():
    """AGENT_ENVS_NUMBA=0: every compiled path off (status and the switches of before say so),
    numba never imported, and the single and the native vector env step on numpy."""
    code = textwrap.dedent(
        """
        import json, sys
        import gymnasium as gym, numpy as np
        import agent_envs
        from agent_envs import native
        from agent_envs.dynamics import laplacian
        from agent_envs.envs import fast_step
        from agent_envs.integrators import exponential, phi_functions
        from agent_envs import draws
        env = gym.make("agent_envs/Swarm-v0", n_agents=60, n_steps=3, n_paths=2)
        env.reset(seed=0)
        for _ in range(3):
            env.step(env.action_space.sample())
        venv = gym.make_vec("agent_envs/Swarm-v0", num_envs=2, n_agents=60, n_steps=3,
                            vectorization_mode="vector_entry_point")
        venv.reset(seed=0)
        for _ in range(4):
            obs, *_ = venv.step(np.zeros(venv.action_space.shape, dtype=np.float32))
        old = [laplacian.load_compiled_kernel(), phi_functions.load_compiled(),
               exponential.fused_step_enabled(), draws.load_compiled_noise(),
               fast_step.load_compiled_step()]
        print(json.dumps({"status": native.status(), "old": old,
                          "finite": bool(np.all(np.isfinite(obs))),
                          "numba": "numba" in sys.modules,
                          "plan": venv.unwrapped.plan.as_dict()}))
        """
    )
    env = {"AGENT_ENVS_NUMBA": "0", "PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["status"] == dict.fromkeys(NAMES, False)
    assert out["old"] == [False] * 5
    assert out["finite"] and not out["numba"]
    assert out["plan"]["envelope"] == "numpy" and out["plan"]["kernel_pass"] == "numpy"


@pytest.mark.parametrize("name", NAMES)
def test_use_turns_one_path_off(restored, name):
    """`use(name, False)`: that path off (and "fused", which needs the kernel pass and the
    Lanczos, with them); the others as they were; `use(name, True)` turns it back on."""
    before = native.status()
    native.use(name, False)
    after = native.status()
    assert after[name] is False
    off = {name} | ({"fused"} if name in ("kernel", "lanczos") else set())
    assert {k: v for k, v in after.items() if k not in off} == {
        k: v for k, v in before.items() if k not in off
    }
    native.use(name, True)
    assert native.status() == before


def test_the_switches_of_before_are_the_one_switch(restored):
    laplacian.use_compiled_kernel(False)
    assert native.status()["kernel"] is False
    phi_functions.use_compiled(False)
    assert not native.available("lanczos") and not native.available("fused")
    exponential.use_fused_step(False)
    assert loader._loaded["fused"] is False
    from agent_envs import draws

    draws.use_compiled_noise(False)
    status = native.status()
    assert not any(status[name] for name in ("kernel", "lanczos", "fused", "noise"))


def test_fused_switched_off_takes_the_general_step_with_the_same_bits(restored, monkeypatch):
    """`use("fused", False)`: a SERB step of the envs' model takes the general path (no fused
    call) and gives the fused step's state bit for bit."""
    if not native.available("fused"):
        pytest.skip("the fused step needs numba")
    from agent_envs import SwarmParams, make_integrator
    from agent_envs.dynamics.linearization_cache import LinearizationCache

    lanczos = native.loaded("lanczos")
    calls = []
    original = lanczos.frozen_advance
    monkeypatch.setattr(lanczos, "frozen_advance", lambda *a: calls.append(1) or original(*a))
    x = np.random.default_rng(0).uniform(-1, 1, (2, 100, 1))
    dw = np.random.default_rng(1).standard_normal(x.shape) * 0.1
    results = []
    for on in (True, False):
        native.use("fused", on)
        model = LinearizationCache(SwarmParams(n_agents=100, sigma=0.1), "dense")
        state = x.copy()
        state.flags.writeable = False
        results.append(make_integrator("serb").step(model, state, None, 0.0, 0.01, dw))
        assert bool(calls) == on
        calls.clear()
    np.testing.assert_array_equal(results[0], results[1])


@pytest.mark.parametrize("call", [native.use, native.available, native.register_check])
def test_unknown_name_is_refused_with_the_known_ones(call):
    args = {native.use: (True,), native.available: (), native.register_check: (bool, "")}[call]
    with pytest.raises(ValueError, match="kernel, lanczos, fused, noise, step") as caught:
        call("lanczoss", *args)
    assert "'lanczoss'" in str(caught.value)
