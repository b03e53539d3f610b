"""The one registry of experiment settings: every preset of `agent-envs compare` and `sweep`.

A `Preset` names one setting: the env kwargs, its env settings (the main one first, then the
contrasts), the learners with their budgets, the reference controllers, the training seeds,
and the evaluation sizes. `compare --preset X` runs one training seed of X (``--seed``, default
the preset's first) on one of its settings (``--setting``, default the main one), in process;
`sweep --preset X` runs the whole grid (learners x seeds x settings) on Ray Tune. The
experiment builder (`agent_envs.training.experiment`) turns a preset and the command line's
changes into runs.

Presets:

- ``smoke``: PPO x 2 training seeds, N = 5 agents, m = 5 steps, 256 timesteps, 5 test
  episodes; a CI check that the whole pipeline runs.
- ``quick``: N = 10, m = 20, otherwise the paper's stiff setting; PPO, SAC and
  parameter-shared PPO with the training layer's hyperparameters, and ``apg``; the main job
  (`agent-envs compare --preset quick`, a few minutes on 2 cores).
- ``paper``: the paper's scale (N = 100, m = 50, eps = 0.05, SERB, 20 Brownian paths,
  max_control = 25): the zoo's tuned Pendulum-v1 entries for PPO, SAC, TD3 and parameter-shared
  PPO, ``ppo-swarm`` (PPO with the training layer's own hyperparameters) and ``apg``; 3 training
  seeds;
  contrasts eps = 1, max_control = 150 and train-on-EM / evaluate-on-SERB. The published study
  (docs/results.md "Results at the paper's scale", docs/results/paper-sweep).

Renamed: before, ``compare --preset paper`` was another setting than ``sweep --preset paper``
(max_control = 150 and 400k PPO steps against 25 and 32 768); it never produced a published
result and is gone: ``paper`` means the published study's setting for both commands.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agent_envs.training.config import read_hyperparams_file
from agent_envs.training.defaults import FEEDBACK_BASELINES, GYM_ENV_ID, PETTINGZOO_ENV_ID


@dataclass(frozen=True)
class Learner:
    """One learner of a preset: an SB3 algorithm on one of the two swarm envs, with its budget.

    `hyperparams` override the training layer's defaults (`config.default_hyperparams`) key by
    key; `timesteps` counts SB3 timesteps (agent-steps on the PettingZoo env). For the `apg`
    learner (algo "apg": `agent_envs.training.apg`) `timesteps` is the number of iterations
    and `hyperparams` are `APGConfig` fields over its defaults.
    """

    name: str
    algo: str
    env_id: str
    timesteps: int
    hyperparams: dict[str, Any] = field(default_factory=dict)
    n_envs: int | None = None
    description: str = ""


@dataclass(frozen=True)
class EnvSetting:
    """One env setting of a preset.

    Args:
        name: short name (used in trial ids and run folder names).
        description: one line for the report.
        env_kwargs: env kwargs for training, over the preset's `Preset.env_kwargs`.
        eval_env_kwargs: kwargs changed for the held-out evaluation only (train on one env,
            evaluate on another); {} evaluates on the training env.
        learners: names of the preset's learners trained in this setting; None: all.
        references: names of the preset's references evaluated in this setting; None: all.
    """

    name: str
    description: str
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    eval_env_kwargs: dict[str, Any] = field(default_factory=dict)
    learners: tuple[str, ...] | None = None
    references: tuple[str, ...] | None = None


@dataclass(frozen=True)
class Preset:
    """An experiment setting: base env kwargs, env settings, learners, seeds, evaluation sizes.

    `references` lists the reference controllers wanted; those not in
    `agent_envs.baselines.BASELINES` of this install are left out (and named in the report).
    `reference_kwargs` maps a reference's name to the keyword arguments its controller is built
    with (`agent_envs.baselines.make_baseline(name, env, **kwargs)`). `vec_env` is the training
    envs' vectorization (`agent-envs train --vec-env`) of the single-controller learners.
    `validation_episodes` and `evaluations` set the validation during training (episodes per
    evaluation, evaluations per run); `test_episodes` the held-out evaluation.
    """

    name: str
    description: str
    env_kwargs: dict[str, Any]
    settings: tuple[EnvSetting, ...]
    learners: tuple[Learner, ...]
    seeds: tuple[int, ...]
    references: tuple[str, ...] = FEEDBACK_BASELINES
    reference_kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)
    test_episodes: int = 20
    validation_episodes: int = 5
    evaluations: int = 8
    vec_env: str = "dummy"
    hyperparams_source: str = ""

    def setting(self, name: str | None = None) -> EnvSetting:
        """The env setting called `name` (None: the main one, the first); ValueError naming
        --setting otherwise."""
        if name is None:
            return self.settings[0]
        for setting in self.settings:
            if setting.name == name:
                return setting
        raise ValueError(
            f"--setting {name!r} is not a setting of the {self.name} preset; it has "
            f"{', '.join(s.name for s in self.settings)}"
        )


#: The optimal-control references (`agent_envs.baselines.optimal_controllers`): they solve an
#: optimization per episode (optimal) or per step (mpc).
OPTIMUM_POLICIES = ("optimal", "mpc")

#: The analytic-policy-gradient learner with `APGConfig`'s defaults (300 iterations, what
#: benchmarks/bench_apg.py measured; docs/learners/apg.md): a per-agent feedback law trained by
#: backpropagation of the discrete cost through the core's SERB.
APG_LEARNER = Learner(
    "apg",
    "apg",
    GYM_ENV_ID,
    300,
    description="APG: a per-agent feedback law trained by backpropagation through SERB",
)

# ------------------------------------------------------------------------------------- smoke

_SMOKE_ENV = {"n_agents": 5, "n_steps": 5}

_SMOKE = Preset(
    name="smoke",
    description=(
        "a CI check of the whole pipeline: PPO x 2 training seeds, N = 5 agents, m = 5 steps, "
        "256 timesteps, 5 test episodes (otherwise the env defaults: eps = 0.05, SERB)"
    ),
    env_kwargs=_SMOKE_ENV,
    settings=(EnvSetting("main", "N = 5, m = 5, SERB"),),
    learners=(
        Learner(
            "ppo",
            "ppo",
            GYM_ENV_ID,
            256,
            {"n_steps": 64, "batch_size": 64, "n_epochs": 2},
            n_envs=2,
            description="PPO, one controller",
        ),
    ),
    seeds=(0, 1),
    test_episodes=5,
    validation_episodes=2,
    evaluations=2,
)

# ------------------------------------------------------------------------------------- quick

_QUICK_ENV = {"n_agents": 10, "n_steps": 20}


def _sac_target_entropy(env_kwargs: dict[str, Any], per_dim: float = -5.0) -> float:
    """SAC's target entropy: `per_dim` per action coordinate (N d of them)."""
    return per_dim * int(env_kwargs.get("n_agents", 100)) * int(env_kwargs.get("dim", 1))


_QUICK = Preset(
    name="quick",
    description=(
        "N = 10 agents, m = 20 steps, otherwise the paper's stiff setting (eps = 0.05, "
        "alpha = 0.1, sigma = 0.01, T = 1, target 0.7, SERB); a few minutes on 2 CPU cores"
    ),
    env_kwargs=_QUICK_ENV,
    settings=(EnvSetting("main", "N = 10, m = 20, eps = 0.05, SERB"),),
    learners=(
        Learner("ppo", "ppo", GYM_ENV_ID, 40_000, description="PPO, one controller"),
        Learner(
            "sac",
            "sac",
            GYM_ENV_ID,
            20_000,
            {"target_entropy": _sac_target_entropy(_QUICK_ENV)},
            description="SAC, one controller",
        ),
        Learner(
            "ppo-shared",
            "ppo",
            PETTINGZOO_ENV_ID,
            150_000,
            description="parameter-shared PPO, one agent per swarm member (SuperSuit)",
        ),
        APG_LEARNER,
    ),
    seeds=(0, 1, 2),
    references=(*FEEDBACK_BASELINES, *OPTIMUM_POLICIES),
    test_episodes=20,
    validation_episodes=10,
    evaluations=8,
    vec_env="native",
)

# ------------------------------------------------------------------------------------- paper

#: Where the paper preset's hyperparameters come from (hyperparams/zoo_pendulum.yml).
PAPER_HYPERPARAMS_SOURCE = (
    "rl-zoo3 (2.9) tuned entries for Pendulum-v1 in hyperparams/ppo.yml, sac.yml and td3.yml "
    "(shipped as training/hyperparams/zoo_pendulum.yml): "
    "the closest of the zoo's tuned continuous-control tasks to this one (smooth dynamics, "
    "dense quadratic cost, short episodes, budgets of 2e4-1e5 steps; PPO's entry already has "
    "gamma = 0.9, the training layer's own choice for 50-step episodes). Keys the zoo entry "
    "leaves out are set to Stable-Baselines3's defaults explicitly, so the training layer's "
    "N = 10 tuning does not leak in. Changed from the zoo: the budgets (n_timesteps); "
    "TD3's learning_starts (2 500 instead of 1e4, a quarter of the halved budget); "
    "the replay buffers hold the whole budget (the zoo's 2e5 / SB3's 1e6 would never fill, and "
    "SB3 allocates them up front: 1.6 GB per SAC run at N = 100); parameter-shared PPO takes "
    "n_steps = 32 per agent so that a rollout holds 3200 samples (a multiple of the zoo's "
    "batch of 64), near the zoo's 4 x 1024; "
    "observation/reward normalization and the horizon-as-termination wrapper stay as in the "
    "training layer."
)

#: The paper's setting (eq:serb for the integrator), 20 Brownian paths.
PAPER_ENV = {
    "n_agents": 100,
    "n_steps": 50,
    "epsilon": 0.05,
    "alpha": 0.1,
    "sigma": 0.01,
    "horizon": 1.0,
    "target": 0.7,
    "integrator": "serb",
    "n_paths": 20,
    # the env's default bound (150) is sized for the paper's turnpike control; good controls are
    # 20x smaller (the optimal control's largest |u| is 7.3-7.5 on test seeds 10000-10001, the
    # proportional controller's 20.2), so learners with the zoo's action noise (tuned for
    # actions of the order of their bound) spend their budget on controls of ~100: 25 leaves
    # the optimal control, MPC and the proportional controller unclipped and clips the turnpike
    # controller (65-67) -- docs/results.md "Results at the paper's scale"
    "max_control": 25.0,
}

# Budgets (SB3 timesteps) of the paper preset, sized so that the whole preset ends in about
# 1.5 h on 2 cores (docs/presets.md "The paper preset: what it runs"; it took 59 min): PPO gets 8
# rollouts of 4 x 1024; SAC and TD3 half the zoo's Pendulum-v1 n_timesteps (1e4 of 2e4; TD3's
# random warm-up is cut further, below); parameter-shared PPO 6e5 agent-steps (SB3 ends on a
# whole rollout: 188 rollouts of 3200 samples, 601 600 agent-steps, 6 016 swarm steps).
PAPER_BUDGETS = {"ppo": 32_768, "sac": 10_000, "td3": 10_000, "ppo-shared": 600_000}


def _zoo_learner(
    name: str,
    algo: str,
    env_id: str,
    description: str,
    n_envs: int | None = None,
    **changes: Any,
) -> Learner:
    """A learner with rl-zoo3's Pendulum-v1 entry for `algo` (zoo_pendulum.yml), `changes`
    applied over it, the paper budget of `name`, and `n_envs` (None: the entry's)."""
    entry = dict(read_hyperparams_file("zoo_pendulum")[algo])
    zoo_envs = int(entry.pop("n_envs"))
    return Learner(
        name,
        algo,
        env_id,
        PAPER_BUDGETS[name],
        {**entry, **changes},
        zoo_envs if n_envs is None else n_envs,
        description,
    )


_PAPER = Preset(
    name="paper",
    description=(
        "the paper's scale: N = 100, m = 50, eps = 0.05, alpha = 0.1, "
        "sigma = 0.01, T = 1, target 0.7, SERB, 20 Brownian paths, max_control = 25"
    ),
    env_kwargs=PAPER_ENV,
    settings=(
        EnvSetting("main", "the paper's stiff setting (eps = 0.05), SERB"),
        EnvSetting(
            "eps1",
            "non-stiff contrast: eps = 1, SERB",
            env_kwargs={"epsilon": 1.0},
            learners=("ppo-swarm", "apg"),
            # MPC re-solves at every step: the main setting only
            references=("optimal", "turnpike", "proportional", "zero"),
        ),
        EnvSetting(
            "bound150",
            "the env's default action bound max_control = 150 (the paper's turnpike "
            "control unclipped; good controls are then ~5% of the action range)",
            env_kwargs={"max_control": 150.0},
            learners=("ppo",),
            references=("optimal", "turnpike", "proportional", "zero"),
        ),
        EnvSetting(
            "em-to-serb",
            "trained with Euler-Maruyama, evaluated with SERB (eps = 0.05)",
            env_kwargs={"integrator": "em"},
            eval_env_kwargs={"integrator": "serb"},
            learners=("ppo-swarm", "apg"),
        ),
    ),
    learners=(
        _zoo_learner("ppo", "ppo", GYM_ENV_ID, "PPO, one controller"),
        Learner(
            "ppo-swarm",
            "ppo",
            GYM_ENV_ID,
            PAPER_BUDGETS["ppo"],
            {},
            None,
            "PPO, one controller, with the training layer's own hyperparameters (tuned on "
            "this env at N = 10: small initial action noise, log_std_init = -3)",
        ),
        # the replay buffers hold the whole budget
        _zoo_learner(
            "sac", "sac", GYM_ENV_ID, "SAC, one controller", buffer_size=PAPER_BUDGETS["sac"]
        ),
        # the zoo's random-action warm-up is 1e4 of a 2e4 budget; at a 1e4 budget that would
        # leave no learning, so 2 500 (a quarter) leaves 7 500 learning steps
        _zoo_learner(
            "td3",
            "td3",
            GYM_ENV_ID,
            "TD3, one controller",
            buffer_size=PAPER_BUDGETS["td3"],
            learning_starts=2_500,
        ),
        _zoo_learner(
            "ppo-shared",
            "ppo",
            PETTINGZOO_ENV_ID,
            "parameter-shared PPO, one agent per swarm member (SuperSuit)",
            n_envs=1,  # one swarm of N agents: SuperSuit's vector env
            n_steps=32,
        ),
        APG_LEARNER,
    ),
    seeds=(0, 1, 2),
    references=("optimal", "mpc", "turnpike", "proportional", "zero"),
    # certainty-equivalent MPC: each re-solve plans on the sigma = 0 model (one path).
    # Re-solving the 20-path sample average at every step costs ~11 s a step at N = 100
    # (~5 min an episode, 1.7 core-h for 20 episodes); the noise-free re-solve ~0.6 s.
    reference_kwargs={"mpc": {"noise_free": True}},
    test_episodes=20,
    validation_episodes=5,
    evaluations=8,
    # trains on the native vector env (`agent-envs train --vec-env native`); `--vec-env
    # dummy` runs the same preset on SB3's DummyVecEnv (bit-identical results, slower)
    vec_env="native",
    hyperparams_source=PAPER_HYPERPARAMS_SOURCE,
)

#: name -> preset, for every experiment command
PRESETS: dict[str, Preset] = {p.name: p for p in (_SMOKE, _QUICK, _PAPER)}


def get_preset(name: str) -> Preset:
    """The preset called `name`; ValueError naming --preset and the known ones otherwise."""
    if name not in PRESETS:
        raise ValueError(f"--preset must be one of {', '.join(PRESETS)}; got {name!r}")
    return PRESETS[name]


__all__ = [
    "OPTIMUM_POLICIES",
    "PAPER_BUDGETS",
    "PAPER_ENV",
    "PAPER_HYPERPARAMS_SOURCE",
    "PRESETS",
    "EnvSetting",
    "Learner",
    "Preset",
    "get_preset",
]
