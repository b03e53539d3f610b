"""The native vector env (`SwarmVectorEnv`) and its SB3 adapter (`NativeVecEnv`).

Env i of the native batch must be the single env reset with seed s + i: the tests step the
native env and Gymnasium's `SyncVectorEnv` over `gym.make` envs side by side, with actions
that make one member diverge mid-episode while the others run to the horizon, and require
equal observations, rewards, flags and infos over several episodes with autoresets.
Gymnasium 1.x has no checker for vector envs (`gymnasium.utils.env_checker` checks single
envs, run on the Gymnasium env in test_envs_gym.py); the space, seeding and autoreset
contracts it would check are tested here directly.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)
from agent_envs.draws import load_compiled_noise
from agent_envs.envs import ENV_ID, SwarmEnv, SwarmVectorEnv, step_plan

#: A member pushed by action +1 with this max_control leaves the threshold within the episode;
#: members driven by small random actions reach the horizon.
DIVERGING = {"n_steps": 10, "max_control": 10.0, "divergence_threshold": 2.5}


def native(num_envs: int, **kwargs) -> gym.vector.VectorEnv:
    return gym.make_vec(
        ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
    )


def sync(num_envs: int, autoreset_mode=AutoresetMode.NEXT_STEP, **kwargs) -> SyncVectorEnv:
    return SyncVectorEnv(
        [lambda: gym.make(ENV_ID, **kwargs) for _ in range(num_envs)],
        autoreset_mode=autoreset_mode,
    )


def actions(rng: np.random.Generator, num_envs: int, size: int) -> np.ndarray:
    """Small random actions, except env 1 which pushes every agent by +1 (it diverges)."""
    a = rng.uniform(-0.3, 0.3, (num_envs, size)).astype(np.float32)
    a[1 % num_envs] = 1.0
    return a


def assert_info_equal(native_info: dict, sync_info: dict) -> None:
    assert set(native_info) == set(sync_info)
    for key, value in sync_info.items():
        if isinstance(value, dict):
            assert_info_equal(native_info[key], value)
        elif value.dtype == object:
            for a, b in zip(native_info[key], value, strict=True):
                assert (a is None and b is None) or np.array_equal(a, b), key
        else:
            np.testing.assert_array_equal(native_info[key], value, err_msg=key)
            assert native_info[key].dtype == value.dtype, key


def run_side_by_side(
    num_envs: int, n_vector_steps: int, seed: int = 11, exact: bool = True, **kwargs
):
    """Step both vector envs; return the number of terminations and truncations seen."""
    venv, senv = native(num_envs, **kwargs), sync(num_envs, **kwargs)
    assert isinstance(venv.unwrapped, SwarmVectorEnv)
    obs_n, info_n = venv.reset(seed=seed)
    obs_s, info_s = senv.reset(seed=seed)
    np.testing.assert_array_equal(obs_n, obs_s)
    assert_info_equal(info_n, info_s)
    rng = np.random.default_rng(0)
    size = senv.single_action_space.shape[0]
    n_terminated = n_truncated = 0
    for _ in range(n_vector_steps):
        a = actions(rng, num_envs, size)
        out_n, out_s = venv.step(a), senv.step(a)
        for got, want in zip(out_n[:4], out_s[:4], strict=True):
            assert got.dtype == want.dtype and got.shape == want.shape
            if exact:
                np.testing.assert_array_equal(got, want)
            else:
                np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
        if exact:
            assert_info_equal(out_n[4], out_s[4])
        assert venv.observation_space.contains(out_n[0])
        n_terminated += int(out_s[2].sum())
        n_truncated += int(out_s[3].sum())
    venv.close()
    senv.close()
    return n_terminated, n_truncated


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_agents": 12},  # SERB, frozen L, phi by expm
        {"n_agents": 100, "n_steps": 6},  # the default setting: phi by Lanczos
        {"n_agents": 60, "n_steps": 6, "phi_method": "eigh"},
        {"n_agents": 8, "dim": 2, "n_paths": 2, "phi_method": "expm"},
        {"n_agents": 8, "dim": 2, "jacobian": "exact", "epsilon": 0.5},
        {"n_agents": 10, "integrator": "em", "epsilon": 0.5},  # eps = 0.05: every EM run diverges
        {
            "n_agents": 10,
            "integrator": "heun",
            "kernel": "nonsymmetric",
            "epsilon_min": 0.3,
            "epsilon_max": 1.0,
        },
        {"n_agents": 12, "integrator": "erb", "target": [-0.5]},
    ],
)
def test_native_matches_sync_vector_env_with_autoreset_and_divergence(kwargs):
    kwargs = {**DIVERGING, **kwargs}
    episode = kwargs["n_steps"]
    terminated, truncated = run_side_by_side(4, 3 * episode + 2, **kwargs)
    assert terminated >= 2  # env 1 diverged in more than one episode, the others went on
    assert truncated >= 6  # the other envs reached the horizon, episode after episode


@pytest.mark.parametrize("integrator", ["em", "serb"])
def test_an_env_that_diverges_on_its_last_step_is_terminated_and_truncated(integrator):
    """gym.make's TimeLimit counts the diverging step: a single env that diverges on the
    horizon step returns terminated and truncated, and so must its native twin (the native env
    once counted only the steps that moved and said truncated=False there)."""
    kwargs = {"n_agents": 10, "n_steps": 1, "max_control": 100.0, "divergence_threshold": 2.5,
              "integrator": integrator, "epsilon": 0.5, "horizon": 0.1}  # fmt: skip
    env = sync(2, **kwargs)
    env.reset(seed=3)
    a = np.full((2, 10), 0.01, dtype=np.float32)
    a[1] = 1.0  # moves every agent of env 1 by 10 in its one step: beyond the threshold
    _, _, terminated, truncated, _ = env.step(a)
    assert terminated.tolist() == [False, True] and truncated.tolist() == [True, True]
    terminated, truncated = run_side_by_side(3, 6, **kwargs)
    assert terminated >= 3 and truncated >= 9


@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_agents": 100, "n_steps": 6},  # Lanczos on the workspace operator
        {"n_agents": 12, "n_paths": 3},  # expm of the operator's dense form
        {"n_agents": 10, "integrator": "em", "epsilon": 0.5},
    ],
)
def test_native_env_in_blocks_matches_sync_vector_env(monkeypatch, kwargs):
    """Blocks of envs (vector_env.BLOCK_BYTES) change nothing: 5 envs in blocks of 2, 2, 1,
    through autoresets and divergence (the block caches are rebuilt after both)."""
    import agent_envs.envs.vector_env as vector_env

    kwargs = {**DIVERGING, **kwargs}
    n = kwargs["n_agents"]
    monkeypatch.setattr(vector_env, "BLOCK_BYTES", 8 * kwargs.get("n_paths", 1) * n * n * 2)
    # blocks are for numpy passes over the batch; with numba every pass runs member by member
    # and the env takes one block: forced here, so the blocks are tested with numba too
    monkeypatch.setattr(step_plan, "member_by_member", lambda *args: False)
    assert SwarmVectorEnv(5, **kwargs).plan.blocks == 3
    terminated, truncated = run_side_by_side(5, 3 * kwargs["n_steps"] + 2, **kwargs)
    assert terminated >= 2
    assert truncated >= 6


def test_steps_after_a_seeded_reset_draw_from_the_new_generators():
    """A seeded reset replaces the envs' generators; the next steps' draws (one compiled call
    over all of them, with numba) come from the new ones: the native env still equals Sync,
    step for step, and its generator handles follow the generators."""
    kwargs = {"n_agents": 20, "n_steps": 30}
    venv, senv = native(3, **kwargs), sync(3, **kwargs)
    a = np.full((3, 20), 0.25, dtype=np.float32)
    for seed in (5, 17, [3, 1, 4]):
        for env in (venv, senv):
            env.reset(seed=seed)
        for _ in range(4):
            got, want = venv.step(a), senv.step(a)
            for g, w in zip(got[:4], want[:4], strict=True):
                np.testing.assert_array_equal(g, w)
        handles = venv.unwrapped._handles
        if load_compiled_noise():  # (the draws took the compiled call, with current handles)
            assert handles is not None and handles.holds(venv.unwrapped.np_randoms)


def test_member_by_member_steps_take_one_block(monkeypatch):
    """With numba's kernel pass and Lanczos every pass runs one system at a time, so the envs
    are not split into blocks (which only add Python per block there); without numba, or for
    a kernel numba does not serve, the BLOCK_BYTES blocks stay."""
    import agent_envs.envs.vector_env as vector_env
    from agent_envs.integrators import phi_functions

    monkeypatch.setattr(vector_env, "BLOCK_BYTES", 8 * 100 * 100 * 2)
    compiled = phi_functions.load_compiled()
    assert SwarmVectorEnv(5, n_agents=100).plan.blocks == (1 if compiled else 3)
    assert SwarmVectorEnv(5, n_agents=100, integrator="em").plan.blocks == (1 if compiled else 3)
    assert SwarmVectorEnv(5, n_agents=100, kernel="nonsymmetric").plan.blocks == 3
    before = phi_functions.use_compiled(False)
    try:
        assert SwarmVectorEnv(5, n_agents=100).plan.blocks == 3
    finally:
        phi_functions.use_compiled(before)
    # a batch whose kernel matrices in one block would exceed the dense budget (where the model
    # goes matrix-free) keeps its blocks: each env stays on the dense path, as alone
    four_envs = 4 * 8 * 3 * 100 * 100  # `dense_bytes` of 4 envs of one path, N = 100, d = 1
    monkeypatch.setattr("agent_envs.dynamics.swarm.DENSE_MEMORY_BUDGET_BYTES", four_envs)
    assert SwarmVectorEnv(5, n_agents=100).plan.blocks == 3


def test_arnoldi_members_match_exactly():
    # Non-symmetric kernel at N = 130: "auto" is Arnoldi, whose batch members also stop one by
    # one, so the vector env is exact there too.
    kwargs = {"n_agents": 130, "kernel": "nonsymmetric", "n_steps": 5}
    # the single env's strategy (its plan's, for its own paths) is the vector env's
    assert SwarmEnv(**kwargs).plan.phi_method == SwarmVectorEnv(1, **kwargs).phi_method == "krylov"
    run_side_by_side(3, 8, **kwargs)


@pytest.mark.parametrize("symmetric", [True, False])
def test_krylov_batch_members_are_computed_as_alone(symmetric):
    # The exactness of the vector env where "auto" is Krylov (Lanczos for the default N = 100,
    # Arnoldi for a non-symmetric kernel at N > 128) rests on this: each member of a batched
    # Krylov phi-action stops at its own dimension, so it equals the unbatched call.
    from agent_envs.integrators.phi_functions import phi_action

    rng = np.random.default_rng(0)
    g = rng.standard_normal((3, 90, 90))
    a = -np.array([0.5, 20.0, 3.0])[:, None, None] * (g @ np.swapaxes(g, -1, -2)) / 90
    if not symmetric:
        a = a + 0.3 * rng.standard_normal(a.shape)
    v = rng.standard_normal((3, 90, 2))
    batched = phi_action(a, v, 1, method="krylov", symmetric=symmetric)
    for i in range(3):
        alone = phi_action(a[i : i + 1], v[i : i + 1], 1, method="krylov", symmetric=symmetric)
        np.testing.assert_array_equal(batched[i], alone[0])


def test_same_step_autoreset_matches_sync():
    kwargs = {**DIVERGING, "n_agents": 10}
    venv = native(3, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    senv = sync(3, autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    np.testing.assert_array_equal(venv.reset(seed=5)[0], senv.reset(seed=5)[0])
    rng = np.random.default_rng(3)
    ended = 0
    for _ in range(25):
        a = actions(rng, 3, 10)
        out_n, out_s = venv.step(a), senv.step(a)
        for got, want in zip(out_n[:4], out_s[:4], strict=True):
            np.testing.assert_array_equal(got, want)
        assert_info_equal(out_n[4], out_s[4])
        ended += int(np.sum(out_s[2] | out_s[3]))
    assert ended >= 4


def test_spaces_and_registration():
    kwargs = {"n_agents": 7, "dim": 2}
    venv = native(5, **kwargs)
    single = gym.make(ENV_ID, **kwargs)
    assert isinstance(venv, SwarmVectorEnv)
    assert venv.num_envs == 5
    assert venv.single_observation_space == single.observation_space
    assert venv.single_action_space == single.action_space
    assert venv.observation_space.shape == (5, *single.observation_space.shape)
    assert venv.action_space.shape == (5, 14)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert venv.spec.id == ENV_ID and venv.spec.kwargs["num_envs"] == 5
    obs, info = venv.reset(seed=0)
    assert venv.observation_space.contains(obs)
    assert info["positions"].shape == (5, 1, 7, 2)
    # actions as (B, N, d) are accepted, as the single env accepts (N, d)
    venv.step(np.zeros((5, 7, 2), dtype=np.float32))


def test_reset_seeding():
    kwargs = {"n_agents": 9, "n_steps": 4}
    venv = native(3, **kwargs)
    obs, _ = venv.reset(seed=40)
    for i in range(3):
        single_obs, _ = gym.make(ENV_ID, **kwargs).reset(seed=40 + i)
        np.testing.assert_array_equal(obs[i], single_obs)
    obs_list, _ = venv.reset(seed=[41, 42, 7])
    np.testing.assert_array_equal(obs_list[:2], obs[1:])
    np.testing.assert_array_equal(obs_list[2], gym.make(ENV_ID, **kwargs).reset(seed=7)[0])
    again, _ = venv.reset(seed=40)
    np.testing.assert_array_equal(again, obs)
    unseeded, _ = venv.reset()  # generators continue: a new start
    assert not np.array_equal(unseeded, obs)
    with pytest.raises(ValueError, match="one entry per env"):
        venv.reset(seed=[1, 2])


def test_reset_options_and_mask():
    kwargs = {"n_agents": 4, "n_steps": 3}
    venv, senv = native(2, **kwargs), sync(2, **kwargs)
    options = {"initial_positions": [0.1, 0.2, 0.3, 0.4], "target": -0.2}
    np.testing.assert_array_equal(
        venv.reset(seed=1, options=options)[0], senv.reset(seed=1, options=options)[0]
    )
    a = np.full((2, 4), 0.1, dtype=np.float32)
    np.testing.assert_array_equal(venv.step(a)[0], senv.step(a)[0])
    mask = np.array([False, True])
    obs_n, info_n = venv.reset(options={"reset_mask": mask.copy()})
    obs_s, info_s = senv.reset(options={"reset_mask": mask.copy()})
    np.testing.assert_array_equal(obs_n, obs_s)
    assert_info_equal(info_n, info_s)
    np.testing.assert_array_equal(info_n["_positions"], mask)
    for _ in range(4):
        out_n, out_s = venv.step(a), senv.step(a)
        for got, want in zip(out_n[:4], out_s[:4], strict=True):
            np.testing.assert_array_equal(got, want)
    with pytest.raises(ValueError, match="unknown reset option"):
        venv.reset(options={"initial_position": [0.0] * 4})


def test_bad_arguments():
    with pytest.raises(TypeError, match="unexpected keyword argument 'x'"):
        native(2, x=1)
    with pytest.raises(ValueError, match="n_agents"):
        native(2, n_agents=1)
    with pytest.raises(ValueError, match="num_envs"):
        SwarmVectorEnv(0)
    with pytest.raises(TypeError, match="num_envs"):
        SwarmVectorEnv(2.0)
    with pytest.raises(ValueError, match="render_mode"):
        SwarmVectorEnv(2, render_mode="rgb_array")
    with pytest.raises(ValueError, match="autoreset_mode"):
        SwarmVectorEnv(2, autoreset_mode="disabled")
    venv = SwarmVectorEnv(2, n_agents=3)
    with pytest.raises(RuntimeError, match="reset"):
        venv.step(np.zeros((2, 3)))
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="actions must have shape"):
        venv.step(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="finite"):
        venv.step(np.full((2, 3), np.nan))


def test_gymnasium_vector_wrappers_run_on_it():
    venv = gym.wrappers.vector.RecordEpisodeStatistics(native(3, n_agents=5, n_steps=4))
    venv.reset(seed=0)
    lengths = []
    for _ in range(9):
        *_, info = venv.step(np.zeros((3, 5), dtype=np.float32))
        if "episode" in info:
            lengths.extend(info["episode"]["l"][info["_episode"]])
    assert lengths == [4, 4, 4, 4, 4, 4]


# ------------------------------------------------------------------ torch / device path
def _torch_matches_numpy(device: str, **kwargs) -> None:
    kwargs = {**DIVERGING, **kwargs}
    on_numpy = SwarmVectorEnv(4, **kwargs)
    on_torch = SwarmVectorEnv(4, device=device, backend="torch", **kwargs)
    assert on_torch._positions.device.type == device.split(":")[0]  # the state stays there
    obs_np, _ = on_numpy.reset(seed=2)
    obs_t, _ = on_torch.reset(seed=2)
    assert isinstance(obs_t, np.ndarray) and obs_t.dtype == np.float32
    np.testing.assert_allclose(obs_t, obs_np, rtol=1e-6, atol=1e-9)
    rng = np.random.default_rng(0)
    n_terminated = 0
    for _ in range(25):
        a = actions(rng, 4, kwargs["n_agents"])
        out_np, out_t = on_numpy.step(a), on_torch.step(a)
        np.testing.assert_allclose(out_t[0], out_np[0], rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(out_t[1], out_np[1], rtol=1e-10, atol=1e-14)
        np.testing.assert_array_equal(out_t[2], out_np[2])
        np.testing.assert_array_equal(out_t[3], out_np[3])
        np.testing.assert_allclose(
            out_t[4]["positions"], out_np[4]["positions"], rtol=1e-10, atol=1e-12
        )
        n_terminated += int(out_np[2].sum())
    assert n_terminated >= 2


@pytest.mark.parametrize("kwargs", [{"n_agents": 12}, {"n_agents": 10, "integrator": "em"}])
def test_torch_backend_on_cpu_matches_numpy(kwargs):
    pytest.importorskip("torch")
    _torch_matches_numpy("cpu", **{"epsilon": 0.5, **kwargs})


@pytest.mark.slow
def test_torch_backend_on_cpu_matches_numpy_at_the_default_size():
    # N = 100, symmetric kernel: the Lanczos phi-action with per-member stopping, on torch
    pytest.importorskip("torch")
    _torch_matches_numpy("cpu", n_agents=100)


def test_torch_tensor_output_and_tensor_actions():
    torch = pytest.importorskip("torch")
    venv = native(3, n_agents=5, backend="torch", tensor_output=True)
    obs, _ = venv.reset(seed=0)
    assert isinstance(obs, torch.Tensor) and obs.dtype == torch.float32
    obs, rewards, terminated, truncated, info = venv.step(torch.zeros(3, 5))
    assert rewards.dtype == torch.float64 and terminated.dtype == truncated.dtype == torch.bool
    assert isinstance(info["positions"], np.ndarray)  # infos stay numpy
    with pytest.raises(ValueError, match="tensor_output"):
        SwarmVectorEnv(2, tensor_output=True)
    with pytest.raises(ValueError, match="backend"):
        SwarmVectorEnv(2, backend="jax")


@pytest.mark.skipif(
    not (
        __import__("importlib").util.find_spec("torch") and __import__("torch").cuda.is_available()
    ),
    reason="needs a CUDA device",
)
def test_cuda_device_matches_numpy():
    _torch_matches_numpy("cuda", n_agents=12, epsilon=0.5)


# ------------------------------------------------------------------ SB3 adapter
