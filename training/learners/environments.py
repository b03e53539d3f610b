"""The envs a training run uses: the Gymnasium env, the vectorized training env and the raw
evaluation env, and the description of the env a run was trained on (``env.json``).
"""

from __future__ import annotations

from typing import Any

from agent_envs.training.config import TrainConfig
from agent_envs.training.defaults import GYM_ENV_ID, default_interface, is_multiagent


def make_gym_env(
    env_id: str, env_kwargs: dict[str, Any] | None = None, option: str = "--env-kwargs"
):
    """`gym.make(env_id, **env_kwargs)` after registering the swarm envs.

    An unknown or mistyped keyword is a ValueError naming `option`.
    """
    import gymnasium as gym

    import agent_envs  # noqa: F401  (registers agent_envs/Swarm-v0)

    try:
        return gym.make(env_id, **(env_kwargs or {}))
    except TypeError as exc:  # unknown or mistyped keyword: a user error, not a crash
        # gym.make re-raises the env's TypeError with the kwargs appended; show the env's own
        original = exc.__context__ if isinstance(exc.__context__, TypeError) else exc
        raise ValueError(f"{option} {env_kwargs}: {original}") from None


def eval_env_kwargs(config: TrainConfig) -> dict[str, Any]:
    """The kwargs of a run's validation env: its own for a Gymnasium learner; for the
    parameter-shared learner the Gymnasium twin with the default interface (its per-agent
    layout is rebuilt from the Gymnasium observation by `PerAgentPolicy`)."""
    if is_multiagent(config.env_id):
        return default_interface(config.env_kwargs)
    return dict(config.env_kwargs)


def eval_env_id(config: TrainConfig) -> str:
    """The Gymnasium env on which a run is evaluated (the PettingZoo env's Gymnasium twin)."""
    return GYM_ENV_ID if is_multiagent(config.env_id) else config.env_id


def make_eval_vec_env(env_id: str, env_kwargs: dict[str, Any] | None, n_episodes: int):
    """Raw (unnormalized) DummyVecEnv with one sub-env per evaluation episode."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    kwargs = dict(env_kwargs or {})
    return DummyVecEnv([lambda: make_gym_env(env_id, kwargs)] * int(n_episodes))


def env_description(
    env_id: str, env_kwargs: dict[str, Any] | None, option: str = "--env-kwargs"
) -> dict[str, Any]:
    """N, d, n_steps, integrator, the step plan and the full kwargs of the Gymnasium env a run
    uses.

    Builds the env once, so it also validates `env_kwargs` (errors name `option`); for the
    PettingZoo id the PettingZoo env (its interface options) and then its Gymnasium twin.
    """
    if is_multiagent(env_id):
        _check_pettingzoo_kwargs(env_kwargs, option)
        description = env_description(GYM_ENV_ID, default_interface(env_kwargs), option)
        return {**description, "env_id": env_id, "env_kwargs": dict(env_kwargs or {})}
    try:
        env = make_gym_env(env_id, env_kwargs, option)
    except ValueError as exc:
        message = str(exc)
        raise ValueError(
            message if message.startswith(option) else f"{option}: {message}"
        ) from None
    try:
        base = env.unwrapped
        params = base.params
        return {
            "env_id": env_id,
            "env_kwargs": dict(env_kwargs or {}),
            "n_agents": int(params.n_agents),
            "dim": int(params.dim),
            "n_steps": int(base.n_steps),
            "integrator": str(base.integrator_name),
            "max_control": float(base.max_control),
            # which code its steps run, resolved when the env was made (this process's
            # compiled paths): `agent_envs.envs.step_plan.StepPlan.describe`
            "step_plan": base.plan.describe(),
        }
    finally:
        env.close()


def training_step_plan(venv: Any) -> str | None:
    """`plan.describe()` of the native vector env a training VecEnv steps (through SB3's
    wrappers and `NativeVecEnv`, their ``venv``), or None for another training env
    (DummyVecEnv, SubprocVecEnv: each sub-env is the env of ``env.json``'s ``step_plan``)."""
    for _ in range(8):  # (a few wrappers at most)
        plan = getattr(venv, "plan", None)
        if plan is not None:
            return str(plan.describe())
        venv = getattr(venv, "venv", None)
        if venv is None:
            return None
    return None


def _check_pettingzoo_kwargs(env_kwargs: dict[str, Any] | None, option: str) -> None:
    """Build the PettingZoo env once: ValueError naming `option` for kwargs it refuses."""
    from agent_envs import swarm_v0

    try:
        swarm_v0.parallel_env(**(env_kwargs or {})).close()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{option} {env_kwargs}: {exc}") from None


def make_training_env(config: TrainConfig, n_envs: int):
    """The vectorized training env (Monitor-wrapped), seeded from config.seed by SB3."""
    if is_multiagent(config.env_id):
        from agent_envs.training.learners.multiagent import make_shared_vec_env

        return make_shared_vec_env(config.env_kwargs, n_copies=n_envs)
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    import agent_envs  # noqa: F401
    from agent_envs.training.learners.wrappers import HorizonAsTermination

    if config.vec_env == "native":
        from agent_envs.training.learners.native_vec_env import NativeVecEnv

        try:
            venv = NativeVecEnv(
                n_envs,
                config.env_kwargs,
                horizon_as_termination=True,
                num_threads=config.env_threads,
            )
        except TypeError as exc:  # unknown keyword: a user error, as in make_gym_env
            raise ValueError(f"--env-kwargs {config.env_kwargs}: {exc}") from None
        venv.seed(config.seed)  # as make_vec_env: env i resets with seed + i
        return venv
    threads = {"num_threads": config.env_threads} if config.env_threads > 1 else {}
    return make_vec_env(
        config.env_id,
        n_envs=n_envs,
        seed=config.seed,
        env_kwargs={**config.env_kwargs, **threads},
        vec_env_cls=SubprocVecEnv if config.vec_env == "subproc" else DummyVecEnv,
        wrapper_class=HorizonAsTermination,
    )
