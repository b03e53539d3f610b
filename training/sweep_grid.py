"""The grid of a sweep, without Ray: presets, env settings, learners, and their trials.

A sweep is a grid (learner x training seed x env setting). Each cell is one *learner trial*:
one `agent_envs.training.train.train` run (its usual run folder under ``OUT/runs``), then an
evaluation of its best model on the held-out test seeds. Each reference controller is one
*reference trial* per distinct evaluation env (the controllers do not train, so the training
seed does not apply; settings that evaluate on the same env share them).

`expand_grid(preset, options)` turns a `SweepPreset` into the list of `Trial`s that
`agent_envs.training.sweep` hands to Ray Tune (one `tune.grid_search` over the trials); it
imports neither Ray nor torch, so the grid is testable on its own.

Presets:

- ``smoke``: 2 trials (PPO x training seeds 0, 1), N = 5 agents, m = 5 steps, 256 timesteps,
  5 test episodes; a CI check that the whole pipeline runs.
- ``paper``: issue 12's study at the paper's scale (N = 100, m = 50, eps = 0.05, alpha = 0.1,
  sigma = 0.01, T = 1, target 0.7, SERB, 20 Brownian paths): PPO, SAC, TD3 on the
  single-controller env and parameter-shared PPO on the PettingZoo env with rl-zoo3's tuned
  entries for Pendulum-v1 (`PAPER_HYPERPARAMS_SOURCE`), and ``ppo-swarm``: PPO with the
  training layer's own hyperparameters; 3 training seeds, max_control = 25. Three contrasts:
  eps = 1 and train with Euler-Maruyama / evaluate with SERB (``ppo-swarm``), and the env's
  default bound max_control = 150 (the zoo's ``ppo``).
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agent_envs.training.config import VEC_ENV_CHOICES, Learner
from agent_envs.training.defaults import (
    DEFAULT_TEST_SEED,
    FEEDBACK_BASELINES,
    GYM_ENV_ID,
    PETTINGZOO_ENV_ID,
    is_multiagent,
)

LEARNER = "learner"
REFERENCE = "reference"
#: a trial's log file (in its run folder, or its reference folder)
TRIAL_LOG = "sweep_trial.log"
#: a learner trial's held-out evaluation, in its run folder
TEST_EVALUATION = "test_evaluation"


@dataclass(frozen=True)
class EnvSetting:
    """One env setting of the grid.

    Args:
        name: short name (used in trial ids and run folder names).
        description: one line for the report.
        env_kwargs: env kwargs for training, over the preset's `SweepPreset.env_kwargs`.
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
class SweepPreset:
    """A sweep: the base env kwargs, the settings, the learners, seeds and evaluation sizes.

    `references` lists the reference controllers wanted; those not in
    `agent_envs.baselines.BASELINES` of this install are left out (and named in the report).
    `reference_kwargs` maps a reference's name to the keyword arguments its controller is built
    with (`agent_envs.baselines.make_baseline(name, env, **kwargs)`).
    `vec_env` is the training envs' vectorization (`agent-envs train --vec-env`) of the
    single-controller learners.
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


@dataclass(frozen=True)
class Trial:
    """One Ray Tune trial: train + evaluate one learner, or evaluate one reference controller.

    `train` is the `TrainConfig` of a learner trial as a dict (None for a reference);
    `eval_env_kwargs` are the full env kwargs of the held-out evaluation; `test_seeds` its
    reset seeds. `settings` lists the env settings whose report uses this trial (a reference
    trial serves every setting evaluated on the same env). `policy_kwargs` are the keyword
    arguments a reference controller is built with (empty: its defaults).
    """

    trial_id: str
    kind: str
    setting: str
    policy: str
    seed: int | None
    eval_env_kwargs: dict[str, Any]
    test_seeds: tuple[int, ...]
    settings: tuple[str, ...] = ()
    train: dict[str, Any] | None = None
    policy_kwargs: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def reference_spec(self) -> Any:
        """The policy spec `evaluate_policies` takes for this reference trial: its registered
        name, or a factory building it with `policy_kwargs` (`make_baseline(name, env, **kw)`).
        """
        if not self.policy_kwargs:
            return self.policy
        from agent_envs.baselines import make_baseline

        return functools.partial(make_baseline, self.policy, **self.policy_kwargs)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Trial:
        values = dict(data)
        values["test_seeds"] = tuple(int(s) for s in values["test_seeds"])
        values["settings"] = tuple(values.get("settings", ()))
        values["policy_kwargs"] = dict(values.get("policy_kwargs") or {})
        return cls(**values)


@dataclass(frozen=True)
class GridOptions:
    """Command-line changes to a preset's grid (None / 1.0: the preset's own)."""

    seeds: tuple[int, ...] | None = None
    learners: tuple[str, ...] | None = None
    settings: tuple[str, ...] | None = None
    timesteps_scale: float = 1.0
    test_episodes: int | None = None
    vec_env: str | None = None


# ------------------------------------------------------------------------------------ presets

_SMOKE_ENV = {"n_agents": 5, "n_steps": 5}

#: Where the paper preset's hyperparameters come from (rl-zoo3 2.9, hyperparams/*.yml).
PAPER_HYPERPARAMS_SOURCE = (
    "rl-zoo3 (2.9) tuned entries for Pendulum-v1 in hyperparams/ppo.yml, sac.yml and td3.yml: "
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

#: The paper's setting (issue 12 item 3; eq:serb for the integrator), 20 Brownian paths.
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
    # controller (65-67) -- README "Results at the paper's scale"
    "max_control": 25.0,
}

# Budgets (SB3 timesteps) of the paper preset, sized so that the whole preset ends in about
# 1.5 h on 2 cores (README "The paper preset: what it runs"; it took 59 min): PPO gets 8
# rollouts of 4 x 1024; SAC and TD3 half the zoo's Pendulum-v1 n_timesteps (1e4 of 2e4; TD3's
# random warm-up is cut further, see _ZOO_TD3); parameter-shared PPO 6e5 agent-steps (SB3 ends
# on a whole rollout: 188 rollouts of 3200 samples, 601 600 agent-steps, 6 016 swarm steps).
PAPER_BUDGETS = {"ppo": 32_768, "sac": 10_000, "td3": 10_000, "ppo-shared": 600_000}

# rl-zoo3 Pendulum-v1 entries (+ SB3 defaults for the keys the entry leaves out).
_ZOO_PPO = {
    "n_steps": 1024,
    "batch_size": 64,  # SB3 default
    "gae_lambda": 0.95,
    "gamma": 0.9,
    "n_epochs": 10,
    "ent_coef": 0.0,
    "learning_rate": 1e-3,
    "clip_range": 0.2,
    "use_sde": True,
    "sde_sample_freq": 4,
    "policy_kwargs": {},  # SB3 default: net_arch [64, 64], log_std_init 0
}
_ZOO_SAC = {
    "learning_rate": 1e-3,
    # SB3 defaults:
    "buffer_size": PAPER_BUDGETS["sac"],
    "learning_starts": 100,
    "batch_size": 256,
    "tau": 0.005,
    "gamma": 0.99,
    "train_freq": 1,
    "gradient_steps": 1,
    "ent_coef": "auto",
    "policy_kwargs": {},
}
_ZOO_TD3 = {
    "gamma": 0.98,
    "buffer_size": PAPER_BUDGETS["td3"],
    # the zoo's random-action warm-up is 1e4 of a 2e4 budget; at a 1e4 budget that would leave
    # no learning, so 2 500 (a quarter) leaves 7 500 learning steps
    "learning_starts": 2_500,
    "noise_type": "normal",
    "noise_std": 0.1,
    "gradient_steps": 1,
    "train_freq": 1,
    "learning_rate": 1e-3,
    "policy_kwargs": {"net_arch": [400, 300]},
    # SB3 defaults:
    "batch_size": 256,
    "tau": 0.005,
}


PRESETS: dict[str, SweepPreset] = {
    "smoke": SweepPreset(
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
    ),
    "paper": SweepPreset(
        name="paper",
        description=(
            "issue 12's study at the paper's scale: N = 100, m = 50, eps = 0.05, alpha = 0.1, "
            "sigma = 0.01, T = 1, target 0.7, SERB, 20 Brownian paths"
        ),
        env_kwargs=PAPER_ENV,
        settings=(
            EnvSetting("main", "the paper's stiff setting (eps = 0.05), SERB"),
            EnvSetting(
                "eps1",
                "non-stiff contrast: eps = 1, SERB",
                env_kwargs={"epsilon": 1.0},
                learners=("ppo-swarm",),
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
                learners=("ppo-swarm",),
            ),
        ),
        learners=(
            Learner(
                "ppo", "ppo", GYM_ENV_ID, PAPER_BUDGETS["ppo"], _ZOO_PPO, 4, "PPO, one controller"
            ),
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
            Learner(
                "sac", "sac", GYM_ENV_ID, PAPER_BUDGETS["sac"], _ZOO_SAC, 1, "SAC, one controller"
            ),
            Learner(
                "td3", "td3", GYM_ENV_ID, PAPER_BUDGETS["td3"], _ZOO_TD3, 1, "TD3, one controller"
            ),
            Learner(
                "ppo-shared",
                "ppo",
                PETTINGZOO_ENV_ID,
                PAPER_BUDGETS["ppo-shared"],
                {**_ZOO_PPO, "n_steps": 32},
                1,
                "parameter-shared PPO, one agent per swarm member (SuperSuit)",
            ),
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
    ),
}


# ---------------------------------------------------------------------------------- expansion


def available_references(preset: SweepPreset) -> tuple[list[str], list[str]]:
    """(references of `preset` this install has, those it lacks) per `BASELINES`."""
    from agent_envs.baselines import BASELINES

    have = [r for r in preset.references if r in BASELINES]
    return have, [r for r in preset.references if r not in BASELINES]


def _select(names: Sequence[str], wanted: Sequence[str] | None, option: str) -> list[str]:
    if wanted is None:
        return list(names)
    unknown = [w for w in wanted if w not in names]
    if unknown:
        raise ValueError(f"{option}: unknown {unknown}; this preset has {', '.join(names)}")
    return [n for n in names if n in wanted]


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text)


def run_name(setting: str, learner: str, seed: int) -> str:
    """The run folder of a learner trial: ``{setting}__{learner}__{seed}`` (no time stamp, so an
    interrupted sweep finds its runs again)."""
    return f"{_safe(setting)}__{_safe(learner)}__{seed}"


def expand_grid(
    preset: SweepPreset, options: GridOptions | None = None, runs_dir: str = "runs"
) -> list[Trial]:
    """The trials of `preset`: learners x seeds x settings, then the reference trials.

    Raises ValueError naming the option for an unknown learner / setting, a bad scale or test
    episode count, or a `vec_env` that `agent-envs train` does not offer.
    """
    from agent_envs.training.config import TrainConfig

    options = options or GridOptions()
    if not (isinstance(options.timesteps_scale, (int, float)) and options.timesteps_scale > 0):
        raise ValueError(f"--timesteps-scale must be > 0, got {options.timesteps_scale!r}")
    n_test = options.test_episodes or preset.test_episodes
    if n_test < 2:
        raise ValueError(f"--test-episodes must be >= 2, got {n_test}")
    seeds = tuple(options.seeds) if options.seeds is not None else preset.seeds
    if not seeds or any(isinstance(s, bool) or not isinstance(s, int) or s < 0 for s in seeds):
        raise ValueError(f"--seeds must be integers >= 0, got {seeds!r}")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds lists a seed twice: {seeds!r}")
    vec_env = options.vec_env or preset.vec_env
    if vec_env not in VEC_ENV_CHOICES:
        raise ValueError(f"--vec-env must be one of {', '.join(VEC_ENV_CHOICES)}, got {vec_env!r}")
    learner_names = _select([lr.name for lr in preset.learners], options.learners, "--learners")
    setting_names = _select([s.name for s in preset.settings], options.settings, "--settings")
    test_seeds = tuple(range(DEFAULT_TEST_SEED, DEFAULT_TEST_SEED + n_test))

    trials: list[Trial] = []
    references_by_env: dict[str, Trial] = {}
    references, _ = available_references(preset)
    for setting in preset.settings:
        if setting.name not in setting_names:
            continue
        train_kwargs = {**preset.env_kwargs, **setting.env_kwargs}
        eval_kwargs = {**train_kwargs, **setting.eval_env_kwargs}
        for learner in preset.learners:
            if learner.name not in learner_names:
                continue
            if setting.learners is not None and learner.name not in setting.learners:
                continue
            timesteps = max(round(learner.timesteps * options.timesteps_scale), 1)
            for seed in seeds:
                config = TrainConfig(
                    algo=learner.algo,
                    env_id=learner.env_id,
                    env_kwargs=train_kwargs,
                    timesteps=timesteps,
                    seed=seed,
                    out=runs_dir,
                    run_name=run_name(setting.name, learner.name, seed),
                    n_envs=learner.n_envs,
                    hyperparams=dict(learner.hyperparams),
                    eval_freq=max(timesteps // preset.evaluations, 1),
                    eval_episodes=preset.validation_episodes,
                    checkpoint_freq=max(timesteps // 4, 1),
                    vec_env="dummy" if is_multiagent(learner.env_id) else vec_env,
                    progress_bar=False,
                    torch_threads=1,
                )
                trials.append(
                    Trial(
                        trial_id=config.run_name or "",
                        kind=LEARNER,
                        setting=setting.name,
                        policy=learner.name,
                        seed=seed,
                        eval_env_kwargs=eval_kwargs,
                        test_seeds=test_seeds,
                        settings=(setting.name,),
                        train=config.to_dict(),
                    )
                )
        for reference in references:
            if setting.references is not None and reference not in setting.references:
                continue
            key = repr(sorted(eval_kwargs.items())) + reference
            if key in references_by_env:
                shared = references_by_env[key]
                references_by_env[key] = dataclasses.replace(
                    shared, settings=(*shared.settings, setting.name)
                )
                continue
            references_by_env[key] = Trial(
                trial_id=f"{_safe(setting.name)}__{reference}",
                kind=REFERENCE,
                setting=setting.name,
                policy=reference,
                seed=None,
                eval_env_kwargs=eval_kwargs,
                test_seeds=test_seeds,
                settings=(setting.name,),
                policy_kwargs=dict(preset.reference_kwargs.get(reference, {})),
            )
    return trials + list(references_by_env.values())


# ------------------------------------------------------------------------ where trials write


def learner_run_dir(trial: Trial, out: Path) -> Path:
    """The run folder of a learner trial under the sweep's output folder `out`."""
    return out / "runs" / str(trial.train["run_name"])


def reference_dir(trial: Trial, out: Path) -> Path:
    """The folder of a reference trial's evaluation."""
    return out / "references" / trial.setting / trial.policy


def evaluation_dir(trial: Trial, out: Path) -> Path:
    """Where a trial's held-out evaluation is saved."""
    if trial.kind == LEARNER:
        return learner_run_dir(trial, out) / TEST_EVALUATION
    return reference_dir(trial, out)


__all__ = [
    "LEARNER",
    "PAPER_ENV",
    "PAPER_HYPERPARAMS_SOURCE",
    "PRESETS",
    "REFERENCE",
    "EnvSetting",
    "GridOptions",
    "Learner",
    "SweepPreset",
    "Trial",
    "available_references",
    "evaluation_dir",
    "expand_grid",
    "learner_run_dir",
    "run_name",
]
