"""The one registry of experiment settings: every preset of `agent-envs compare` and `sweep`.

A `Preset` names one setting: the env kwargs, its env settings (the main one first, then the
contrasts), the learners with their budgets, the reference controllers, the training seeds,
and the evaluation sizes. `compare --preset X` runs one training seed of X (``--seed``, default
the preset's first) on one of its settings (``--setting``, default the main one), in process;
`sweep --preset X` runs the whole grid (learners x seeds x settings) on Ray Tune. The
experiment builder (`agent_envs.training.commands.experiment`) turns a preset and the command line's
changes into runs.

Presets:

- ``smoke``: PPO x 2 training seeds, N = 5 agents, m = 5 steps, 256 timesteps, 5 test
  episodes; a CI check that the whole pipeline runs.
- ``quick``: the paper's study in miniature, the main job (`agent-envs compare --preset
  quick`, about two minutes on 2 cores): N = 10, m = 20, otherwise the paper's stiff setting
  with max_control = 25; the paper preset's learners with their interfaces and
  hyperparameters at budgets chosen on the validation seeds (docs/presets.md), and
  ``apg``; the references are the optimum (no MPC: it equals the optimum at sigma = 0.01), the
  feedback controllers and ``proportional-common``, the summary/common learners' fair baseline
  (`agent_envs.training.commands.interface_references`).
- ``paper``: the paper's scale (N = 100, m = 50, eps = 0.05, SERB, 20 Brownian paths,
  max_control = 25): PPO, SAC and TD3 on the summary observation with one common control, PPO on
  the full state and control in the modes basis, parameter-shared PPO with the swarm
  observation and the team reward (hyperparams/paper.yml; env options: docs/env-options.md), and
  ``apg``; 3 training seeds;
  contrasts eps = 1, max_control = 150 and train-on-EM / evaluate-on-SERB; the references are
  the optimum, MPC (main setting), the feedback controllers and ``proportional-common``. The
  published study
  (docs/results.md "Results at the paper's scale", docs/results/paper-sweep).

Renamed: before, ``compare --preset paper`` was another setting than ``sweep --preset paper``
(max_control = 150 and 400k PPO steps against 25 and 32 768); it never produced a published
result and is gone: ``paper`` means the published study's setting for both commands.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from agent_envs.training.commands.interface_references import CENTRE_LAW
from agent_envs.training.config import read_hyperparams_file
from agent_envs.training.defaults import FEEDBACK_BASELINES, GYM_ENV_ID, PETTINGZOO_ENV_ID


@dataclass(frozen=True)
class Learner:
    """One learner of a preset: an SB3 algorithm on one of the two swarm envs, with its budget.

    `hyperparams` override the training layer's defaults (`config.default_hyperparams`) key by
    key; `timesteps` counts SB3 timesteps (agent-steps on the PettingZoo env). For the `apg`
    learner (algo "apg": `agent_envs.training.learners.apg`) `timesteps` is the number of iterations
    and `hyperparams` are `APGConfig` fields over its defaults. `env_kwargs` are the learner's
    own env options over the setting's: its interface (`agent_envs.envs.interface`:
    observation layout, action basis, agent reward), which never changes the dynamics, the cost
    or the draws; the learned policy is evaluated on the setting's env through
    `agent_envs.training.learners.policies.InterfacePolicy` / `PerAgentPolicy`. `normalize` is
    `agent-envs train --normalize` (VecNormalize; None: the hyperparameter file's choice).
    """

    name: str
    algo: str
    env_id: str
    timesteps: int
    hyperparams: dict[str, Any] = field(default_factory=dict)
    n_envs: int | None = None
    description: str = ""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    normalize: bool | None = None


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

# ------------------------------------------------------------------------------------- paper

#: Where the paper preset's hyperparameters come from (hyperparams/paper.yml).
PAPER_HYPERPARAMS_SOURCE = (
    "training/hyperparams/paper.yml: the training layer's hyperparameters (hyperparams/ppo.yml, "
    "sac.yml, td3.yml) with the changes that file records and the study that chose them; "
    "replay buffers hold the whole budget. Each learner's env options (observation layout, "
    "action basis, agent reward; docs/env-options.md) are given with it."
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
    # 20x smaller (on the validation seeds 1000-1004 the optimal control's largest |u| is 7.95,
    # the proportional controller's 20.4: benchmarks/env_options.py, docs/env-options.md's
    # design figures; chosen first on test seeds, re-derived on validation seeds with the same
    # outcome), so learners with the zoo's action noise (tuned for
    # actions of the order of their bound) spend their budget on controls of ~100: 25 leaves
    # the optimal control, MPC and the proportional controller unclipped and clips the turnpike
    # controller (65-67) -- docs/results.md "Results at the paper's scale"
    "max_control": 25.0,
}

# Budgets (SB3 timesteps; agent-steps for the parameter-shared learner) of the paper preset,
# first sized for about an hour on 2 cores; since issue 41 (ppo-shared's doubled budget and
# ppo-local) a run from scratch takes about 3 hours on 2 cores (docs/presets.md).
PAPER_BUDGETS = {
    "ppo": 98_304,
    "ppo-modes": 98_304,
    "sac": 20_000,
    "td3": 20_000,
    "ppo-shared": 2_457_600,
    "ppo-local": 1_228_800,
}

#: The single controller's interface in the paper preset: the swarm's centre offset, spread,
#: target and time; one control broadcast to every agent (docs/env-options.md).
SUMMARY_COMMON = {"observation": "summary", "action_basis": "common"}
#: Full information in the centre-and-differences basis: nothing of the state or the control
#: is left out, the common mode is one coordinate.
MODES_MODES = {"observation": "modes", "action_basis": "modes"}
#: The parameter-shared learner's interface: each agent sees its offset, its drift, the swarm's
#: centre offset and spread; every agent is rewarded with the swarm's reward.
SWARM_TEAM = {"observation": "swarm", "agent_reward": "team"}
#: The local learner's interface: each agent sees its own offset to the target, its K = 6
#: nearest neighbours' relative positions and t / T, no global statistic
#: (`agent_envs.envs.local_observation`); every agent is rewarded with the swarm's reward.
LOCAL_TEAM = {"observation": "local", "neighbours": 6, "agent_reward": "team"}


def _paper_learner(
    name: str,
    algo: str,
    env_id: str,
    env_kwargs: dict[str, Any],
    description: str,
    timesteps: int | None = None,
    **changes: Any,
) -> Learner:
    """A learner of the paper preset: its entry of hyperparams/paper.yml (n_envs and normalize
    apart, as rl-zoo3 reads them), `changes` over it, its budget (`timesteps`, default the
    paper's `PAPER_BUDGETS`) and env options."""
    entry = dict(read_hyperparams_file("paper")[name])
    n_envs = int(entry.pop("n_envs"))
    normalize = entry.pop("normalize", None)
    return Learner(
        name,
        algo,
        env_id,
        PAPER_BUDGETS[name] if timesteps is None else timesteps,
        {**entry, **changes},
        n_envs,
        description,
        env_kwargs,
        normalize,
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
            learners=("ppo", "sac", "ppo-shared", "ppo-local", "apg"),
            # MPC re-solves at every step: the main setting only
            references=("optimal", "turnpike", "proportional", "zero", CENTRE_LAW),
        ),
        EnvSetting(
            "bound150",
            "the env's default action bound max_control = 150 (the paper's turnpike "
            "control unclipped; good controls are then ~5% of the action range)",
            env_kwargs={"max_control": 150.0},
            learners=("ppo",),
            references=("optimal", "turnpike", "proportional", "zero", CENTRE_LAW),
        ),
        EnvSetting(
            "em-to-serb",
            "trained with Euler-Maruyama, evaluated with SERB (eps = 0.05)",
            env_kwargs={"integrator": "em"},
            eval_env_kwargs={"integrator": "serb"},
            learners=("ppo", "sac", "apg"),
        ),
    ),
    learners=(
        _paper_learner(
            "ppo",
            "ppo",
            GYM_ENV_ID,
            SUMMARY_COMMON,
            "PPO, one controller: summary observation, common control",
        ),
        _paper_learner(
            "ppo-modes",
            "ppo",
            GYM_ENV_ID,
            MODES_MODES,
            "PPO, one controller: full state and control in the centre-and-differences basis",
        ),
        _paper_learner(
            "sac",
            "sac",
            GYM_ENV_ID,
            SUMMARY_COMMON,
            "SAC, one controller: summary observation, common control",
            buffer_size=PAPER_BUDGETS["sac"],
        ),
        _paper_learner(
            "td3",
            "td3",
            GYM_ENV_ID,
            SUMMARY_COMMON,
            "TD3, one controller: summary observation, common control",
            buffer_size=PAPER_BUDGETS["td3"],
        ),
        _paper_learner(
            "ppo-shared",
            "ppo",
            PETTINGZOO_ENV_ID,
            SWARM_TEAM,
            "parameter-shared PPO (SuperSuit): swarm observation, team reward",
        ),
        _paper_learner(
            "ppo-local",
            "ppo",
            PETTINGZOO_ENV_ID,
            LOCAL_TEAM,
            "parameter-shared PPO (SuperSuit): local observation (own offset, 6 nearest "
            "neighbours), team reward",
        ),
        APG_LEARNER,
    ),
    seeds=(0, 1, 2),
    # CENTRE_LAW: the fair baseline of the summary/common learners and of the swarm row
    references=("optimal", "mpc", "turnpike", "proportional", "zero", CENTRE_LAW),
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

# ------------------------------------------------------------------------------------- quick

#: The quick preset's env: the paper's setting in miniature (N = 10, m = 20, one Brownian
#: path), with the paper's action bound.
QUICK_ENV = {"n_agents": 10, "n_steps": 20, "max_control": 25.0}

#: Budgets of the quick preset (SB3 timesteps; agent-steps for the parameter-shared learner),
#: chosen on the validation seeds (docs/presets.md).
QUICK_BUDGETS = {"ppo": 16_384, "sac": 6_000, "ppo-shared": 76_800, "apg": 150}

#: The parameter-shared learner's network of hyperparams/paper.yml with SB3's orthogonal
#: initialization (gain 0.01 on the action head): its initial policy is then close to the zero
#: control. With the entry's ortho_init = false, training seed 2 was at 6.6 on the validation
#: seeds at its first validation (9x the zero control) and still at 3.5 after 76 800
#: agent-steps, the bad start the paper study met at N = 100 (docs/presets.md).
_QUICK_SHARED_POLICY = {
    **read_hyperparams_file("paper")["ppo-shared"]["policy_kwargs"],
    "ortho_init": True,
}

_QUICK = Preset(
    name="quick",
    description=(
        "the paper's study in miniature: N = 10 agents, m = 20 steps, otherwise the paper's "
        "stiff setting (eps = 0.05, alpha = 0.1, sigma = 0.01, T = 1, target 0.7, SERB, "
        "max_control = 25); the paper's learners, interfaces and hyperparameters"
    ),
    env_kwargs=QUICK_ENV,
    settings=(EnvSetting("main", "N = 10, m = 20, eps = 0.05, SERB"),),
    learners=(
        _paper_learner(
            "ppo",
            "ppo",
            GYM_ENV_ID,
            SUMMARY_COMMON,
            "PPO, one controller: summary observation, common control",
            timesteps=QUICK_BUDGETS["ppo"],
        ),
        _paper_learner(
            "sac",
            "sac",
            GYM_ENV_ID,
            SUMMARY_COMMON,
            "SAC, one controller: summary observation, common control",
            timesteps=QUICK_BUDGETS["sac"],
            buffer_size=QUICK_BUDGETS["sac"],
        ),
        # the published quick table's learner: the paper entry's network with ortho_init and
        # without observation normalization (the paper preset normalizes since issue 41; at
        # N = 10 the budget chosen on the validation seeds learns without it)
        dataclasses.replace(
            _paper_learner(
                "ppo-shared",
                "ppo",
                PETTINGZOO_ENV_ID,
                SWARM_TEAM,
                "parameter-shared PPO (SuperSuit): swarm observation, team reward",
                timesteps=QUICK_BUDGETS["ppo-shared"],
                policy_kwargs=_QUICK_SHARED_POLICY,
            ),
            normalize=False,
        ),
        dataclasses.replace(APG_LEARNER, timesteps=QUICK_BUDGETS["apg"]),
    ),
    seeds=(0, 1, 2),
    references=("optimal", *FEEDBACK_BASELINES, CENTRE_LAW),
    test_episodes=20,
    validation_episodes=10,
    evaluations=12,
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
    "LOCAL_TEAM",
    "OPTIMUM_POLICIES",
    "PAPER_BUDGETS",
    "PAPER_ENV",
    "PAPER_HYPERPARAMS_SOURCE",
    "PRESETS",
    "QUICK_BUDGETS",
    "QUICK_ENV",
    "SWARM_TEAM",
    "EnvSetting",
    "Learner",
    "Preset",
    "get_preset",
]
