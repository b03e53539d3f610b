"""The compiled passes on several threads (`num_threads` of the native vector env,
`SwarmModel.threads`): the same bits as one thread, and clear errors for bad values.

The threaded drivers (`native.kernel.cucker_smale_drift_threads`,
`native.lanczos.frozen_advance_threads`) split the members into contiguous spans, one per
thread, and run the one-thread loop on each span; a member's result does not depend on the
others, so the results must equal the one-thread call's bit for bit, whatever the spans.
Skipped without numba; the threaded cases need numba to allow at least 2 threads.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from test_vector_env import DIVERGING, actions, assert_info_equal, native, sync

from agent_envs import SwarmModel, SwarmParams
from agent_envs.dynamics import laplacian
from agent_envs.dynamics.laplacian import check_compiled_threads, max_compiled_threads
from agent_envs.integrators import phi_functions
from agent_envs.native import loader

try:
    import numba
except ImportError:
    numba = None

# (the validation tests below run without numba too)
needs_two = pytest.mark.skipif(
    numba is None
    or not laplacian.load_compiled_kernel()
    or not phi_functions.load_compiled()
    or max_compiled_threads() < 2,
    reason="no numba, AGENT_ENVS_NUMBA=0, or numba allows one thread here",
)


def spread_states(rng: np.random.Generator, members: int, n: int, d: int) -> np.ndarray:
    """Uniform starts on [-1, 1]^d, the spread states of an episode's first steps."""
    return rng.uniform(-1.0, 1.0, (members, n, d))


@needs_two
@pytest.mark.parametrize("members, chunks, d", [(7, 2, 1), (7, 3, 1), (2, 2, 2), (3, 5, 1)])
def test_threaded_kernel_pass_equals_one_thread(members, chunks, d):
    from agent_envs.native import kernel

    rng = np.random.default_rng(members + chunks)
    x = laplacian.readonly_view(spread_states(rng, members, 30, d))
    outs = []
    for threaded in (False, True):
        p = np.full((members, 30, 30), np.nan)
        s, drift = np.empty((members, 30)), np.empty((members, 30, d))
        if threaded:
            with laplacian.compiled_threads(2):
                kernel.cucker_smale_drift_threads(x, 0.3, 0.01, p, s, drift, chunks)
        else:
            kernel.cucker_smale_drift(x, 0.3, 0.01, p, s, drift)
        outs.append((np.tril(p), s, drift))
    for got, want in zip(outs[1], outs[0], strict=True):
        np.testing.assert_array_equal(got, want)
    assert np.all(np.isfinite(outs[1][0]))  # every member's triangle written: no span left out


def _advance_inputs(rng: np.random.Generator, members: int, spread: float):
    """The arguments of one fused SERB step at N = 40 from states of that spread: P, s, the
    right-hand side, x and the noise, as the env's model and integrator hand them over."""
    from agent_envs.native import kernel

    n = 40
    x = laplacian.readonly_view(spread * rng.uniform(-1.0, 1.0, (members, n, 1)))
    p = np.empty((members, n, n))
    s, drift = np.empty((members, n)), np.empty((members, n, 1))
    kernel.cucker_smale_drift(x, 20.0, 0.01, p, s, drift)
    rhs = laplacian.readonly_view(drift + rng.uniform(-1.0, 1.0, (members, 1, 1)))
    noise = laplacian.readonly_view(0.1 * rng.standard_normal((members, n, 1)))
    return p, laplacian.readonly_view(s), rhs, x, noise


@needs_two
@pytest.mark.parametrize("spread", [1.0, 1e-3])  # an episode's first steps; near consensus
@pytest.mark.parametrize("members, chunks", [(9, 2), (5, 3), (2, 2)])
@pytest.mark.parametrize("with_noise_product", [True, False])
def test_threaded_fused_step_equals_one_thread(spread, members, chunks, with_noise_product):
    from agent_envs.native import lanczos

    rng = np.random.default_rng(members)
    p, s, rhs, x, noise = _advance_inputs(rng, members, spread)
    n, dt = x.shape[1], 0.02
    extra = noise if with_noise_product else np.empty((0, 0, 0))
    results = []
    for threaded in (False, True):
        pw = p.copy()
        out, x_next = np.empty((members, n, 1)), np.empty((members, n, 1))
        s_next, drift_next = np.empty((members, n)), np.empty((members, n, 1))
        args = (pw, s, dt * 20.0 / 0.01 / 20.0, rhs, 1e-10, 100, 8, 20.0 / 0.01, out, extra,
                1.0 / dt, x, dt, noise, 20.0, 0.01, x_next, s_next, drift_next)  # fmt: skip
        if threaded:
            with laplacian.compiled_threads(2):
                failed = lanczos.frozen_advance_threads(*args, chunks)
        else:
            failed = lanczos.frozen_advance(*args)
        assert failed == 0
        results.append((np.tril(pw), out, x_next, s_next, drift_next))
    for got, want in zip(results[1], results[0], strict=True):
        np.testing.assert_array_equal(got, want)
    assert not np.array_equal(results[0][2], x)  # the step moved the states


@needs_two
@pytest.mark.parametrize(
    "kwargs, fused",
    [
        ({"n_agents": 100, "n_steps": 6}, True),  # SERB, frozen L(x), Lanczos: the fused step
        ({"n_agents": 100, "n_steps": 6, "n_paths": 3}, True),  # 4 envs x 3 paths: 12 members
        ({"n_agents": 100, "n_steps": 6, "integrator": "erb"}, True),
        ({"n_agents": 40, "n_steps": 6}, False),  # phi by expm: the threaded kernel pass only
        ({"n_agents": 10, "integrator": "em", "epsilon": 0.5}, False),
    ],
)
def test_native_env_on_two_threads_matches_sync_vector_env(monkeypatch, kwargs, fused):
    """The native env on 2 threads against SyncVectorEnv over single envs (one thread), bit for
    bit, through autoresets and a diverging env, as the one-thread env is
    (tests/test_vector_env.py); the threaded kernel pass runs in every case, the threaded
    fused step where SERB or ERB take Lanczos."""
    from agent_envs.native import kernel, lanczos

    calls = {"kernel": 0, "fused": 0}

    def counted(name, function):
        def call(*args):
            calls[name] += 1
            return function(*args)

        return call

    kernel_pass = counted("kernel", kernel.cucker_smale_drift_threads)
    monkeypatch.setattr(loader.loaded("kernel"), "cucker_smale_drift_threads", kernel_pass)
    fused_step = counted("fused", lanczos.frozen_advance_threads)
    monkeypatch.setattr(loader.loaded("lanczos"), "frozen_advance_threads", fused_step)
    kwargs = {**DIVERGING, **kwargs}
    venv, senv = native(4, num_threads=2, **kwargs), sync(4, **kwargs)
    assert venv.unwrapped.num_threads == 2
    assert all(model.threads == 2 for model in venv.unwrapped._blocks.models)
    obs_n, info_n = venv.reset(seed=3)
    obs_s, info_s = senv.reset(seed=3)
    calls.update(kernel=0, fused=0)  # (the first reset's one-time load may have called them)
    np.testing.assert_array_equal(obs_n, obs_s)
    assert_info_equal(info_n, info_s)
    rng = np.random.default_rng(0)
    size = senv.single_action_space.shape[0]
    ended = 0
    for _ in range(3 * kwargs["n_steps"] + 2):
        a = actions(rng, 4, size)
        out_n, out_s = venv.step(a), senv.step(a)
        for got, want in zip(out_n[:4], out_s[:4], strict=True):
            np.testing.assert_array_equal(got, want)
        assert_info_equal(out_n[4], out_s[4])
        ended += int(np.sum(out_s[2] | out_s[3]))
    assert ended >= 8  # autoresets happened, so the threaded steps ran over new episodes
    assert calls["kernel"] > 0
    assert (calls["fused"] > 0) == fused


@needs_two
def test_threads_are_used_and_the_thread_count_is_restored(monkeypatch):
    """A SERB step of a 2-thread env goes through the threaded fused step (the path is not
    dead), and numba's thread count of the calling thread is the same after the step."""
    from agent_envs.native import lanczos

    calls = []
    threaded = lanczos.frozen_advance_threads

    def counting(*args):
        calls.append(numba.get_num_threads())
        return threaded(*args)

    monkeypatch.setattr(loader.loaded("lanczos"), "frozen_advance_threads", counting)
    env = native(4, num_threads=2, n_agents=100)  # (Lanczos from N = 49 on)
    env.reset(seed=0)
    calls.clear()  # (the first reset's one-time load called it too)
    before = numba.get_num_threads()
    numba.set_num_threads(1)  # the caller's own setting, which the step must restore
    try:
        env.step(np.zeros((4, 100), dtype=np.float32))
        assert calls == [2]
        assert numba.get_num_threads() == 1
    finally:
        numba.set_num_threads(before)


@needs_two
def test_async_vector_env_forks_after_making_a_threaded_env():
    """Gymnasium's AsyncVectorEnv makes one env in the parent (for its spaces) and then forks:
    the constructor must not start numba's threads (GNU OpenMP terminates a forked child that
    uses them), so the workers step on 2 threads. In a fresh interpreter: this test process
    has started the threads already."""
    code = textwrap.dedent(
        """
        import multiprocessing, numpy as np, gymnasium as gym, agent_envs
        assert multiprocessing.get_start_method() == "fork"
        kwargs = dict(n_agents=100, n_steps=4, n_paths=2)
        envs = {k: gym.make_vec("agent_envs/Swarm-v0", num_envs=2, vectorization_mode=mode,
                                **kwargs, **extra)
                for k, mode, extra in (("async", "async", {"num_threads": 2}),
                                       ("sync", "sync", {}))}
        first = [env.reset(seed=1)[0] for env in envs.values()]
        assert np.array_equal(*first)
        for _ in range(6):
            a = np.full((2, 100), 0.1, dtype=np.float32)
            out = [env.step(a) for env in envs.values()]
            for got, want in zip(out[0][:4], out[1][:4]):
                assert np.array_equal(got, want)
        for env in envs.values():
            env.close()
        print("ok")
        """
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "ok"


def test_a_pickled_model_keeps_at_most_this_processs_threads(monkeypatch):
    model = SwarmModel(SwarmParams(n_agents=10))
    model._threads = 3  # as pickled in a process that allowed 3
    monkeypatch.setitem(loader._loaded, "kernel", False)  # here: no compiled passes
    loaded = pickle.loads(pickle.dumps(model))
    assert loaded.threads == 1


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2", True, None])
def test_bad_num_threads_is_named(bad):
    error = TypeError if not isinstance(bad, int) or isinstance(bad, bool) else ValueError
    with pytest.raises(error, match="num_threads"):
        native(2, num_threads=bad, n_agents=10)


def test_num_threads_above_numbas_limit_is_named():
    most = max_compiled_threads()
    if most == 1:  # no numba (or switched off): the message says what to install
        message = "num_threads=2: threads need the compiled passes"
    else:
        message = rf"num_threads must be an int in \[1, {most}\]"
    with pytest.raises(ValueError, match=message):
        native(2, num_threads=most + 1, n_agents=10)


def test_model_threads_setter_checks_its_value():
    model = SwarmModel(SwarmParams(n_agents=10))
    assert model.threads == 1
    with pytest.raises(ValueError, match="threads"):
        model.threads = 0
    with pytest.raises(TypeError, match="threads"):
        model.threads = 2.0
    assert model.threads == 1


def test_threads_without_numba_ask_for_it(monkeypatch):
    """(Runs with or without numba: the compiled passes are switched off here.)"""
    monkeypatch.setitem(loader._loaded, "kernel", False)
    assert max_compiled_threads() == 1
    assert check_compiled_threads(1) == 1
    with pytest.raises(ValueError, match="numba"):
        check_compiled_threads(2)


@needs_two
def test_threads_need_the_numpy_backend():
    pytest.importorskip("torch")
    with pytest.raises(ValueError, match="num_threads > 1 needs the numpy backend"):
        native(2, num_threads=2, backend="torch", n_agents=10)


@needs_two
@pytest.mark.parametrize("integrator", ["serb", "em"])
def test_single_env_on_two_threads_matches_one_thread(integrator):
    """The single env's 20 paths on 2 threads: the same observations, rewards and infos as on
    one, over two episodes of the paper setting (the fused SERB step, the kernel pass)."""
    import gymnasium as gym

    from agent_envs.envs import ENV_ID

    kwargs = {"n_paths": 20, "n_steps": 8, "integrator": integrator}
    if integrator == "em":
        kwargs["epsilon"] = 0.5  # (at 0.05 every EM run diverges)
    one = gym.make(ENV_ID, **kwargs)
    two = gym.make(ENV_ID, num_threads=2, **kwargs)
    assert two.unwrapped.num_threads == 2 and two.unwrapped.model.threads == 2
    rng = np.random.default_rng(5)
    for seed in (0, 1):
        np.testing.assert_array_equal(one.reset(seed=seed)[0], two.reset(seed=seed)[0])
        for _ in range(8):
            a = rng.uniform(-0.5, 0.5, one.action_space.shape).astype(np.float32)
            out_one, out_two = one.step(a), two.step(a)
            for got, want in zip(out_two[:4], out_one[:4], strict=True):
                np.testing.assert_array_equal(got, want)
            for key, value in out_one[4].items():
                np.testing.assert_array_equal(out_two[4][key], value, err_msg=key)


def test_single_env_rejects_bad_num_threads():
    import gymnasium as gym

    from agent_envs.envs import ENV_ID

    with pytest.raises(ValueError, match="num_threads"):
        gym.make(ENV_ID, num_threads=0)
