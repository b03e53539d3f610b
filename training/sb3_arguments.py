"""Which Stable-Baselines3 keyword arguments ``--hyperparams`` may set, and their ranges.

`check_hyperparams(algo, hyperparams, policy)` checks a JSON object of SB3 keyword arguments
before anything is built: a key must be an argument of the algorithm's constructor (read from
its signature with `inspect`, so a new SB3 argument is accepted without a change here), or
rl-zoo3's ``noise_type`` / ``noise_std`` for the off-policy algorithms; the common ones are
range-checked (`HYPERPARAM_RANGES`); ``policy_kwargs`` keys must be arguments of the policy
class and expressible in JSON. Errors are ValueErrors naming ``--hyperparams`` and the key.
"""

from __future__ import annotations

import difflib
import inspect
import math
import re
from typing import Any

from agent_envs.training.defaults import algorithm_class

#: rl-zoo3 keys turned into an SB3 action-noise object (TD3).
NOISE_KEYS = ("noise_type", "noise_std")

_REAL, _INT, _BOOL = "a real number", "an integer", "true or false"
#: Range checks of the common SB3 keyword arguments: name -> (kind, low, high, low open).
#: Keys not listed here but in the algorithm's signature are passed on unchecked (SB3 checks
#: them when the model is built).
HYPERPARAM_RANGES: dict[str, tuple[str, float | None, float | None, bool]] = {
    "learning_rate": (_REAL, 0.0, 10.0, True),
    "n_steps": (_INT, 1, 10**9, False),
    "batch_size": (_INT, 2, 10**9, False),
    "n_epochs": (_INT, 1, 10**6, False),
    "gamma": (_REAL, 0.0, 1.0, False),
    "gae_lambda": (_REAL, 0.0, 1.0, False),
    "clip_range": (_REAL, 0.0, None, True),
    "vf_coef": (_REAL, 0.0, None, False),
    "max_grad_norm": (_REAL, 0.0, None, True),
    "buffer_size": (_INT, 1, 10**9, False),
    "learning_starts": (_INT, 0, None, False),
    "tau": (_REAL, 0.0, 1.0, True),
    "gradient_steps": (_INT, -1, 10**6, False),
    "policy_delay": (_INT, 1, 10**6, False),
    "target_policy_noise": (_REAL, 0.0, None, False),
    "target_noise_clip": (_REAL, 0.0, None, False),
    "target_update_interval": (_INT, 1, None, False),
    "sde_sample_freq": (_INT, -1, None, False),
    "stats_window_size": (_INT, 1, 10**6, False),
    "rms_prop_eps": (_REAL, 0.0, None, True),
    "noise_std": (_REAL, 0.0, None, False),
    "use_sde": (_BOOL, None, None, False),
    "use_rms_prop": (_BOOL, None, None, False),
    "normalize_advantage": (_BOOL, None, None, False),
    "use_sde_at_warmup": (_BOOL, None, None, False),
    "optimize_memory_usage": (_BOOL, None, None, False),
}
#: Keyword arguments set by other options (or needing Python objects), not by --hyperparams.
_NOT_FROM_JSON = {
    "policy": "the algorithm's default policy is used",
    "env": "set by --env-id and --env-kwargs",
    "seed": "set by --seed",
    "device": "set by --device",
    "verbose": "set by --verbose",
    "tensorboard_log": "set by --tensorboard",
    "_init_setup_model": "internal to SB3",
    "action_noise": "use noise_type and noise_std",
    "rollout_buffer_class": "a Python class cannot be given as JSON",
    "replay_buffer_class": "a Python class cannot be given as JSON",
}
#: policy_kwargs that can be given as JSON, with their kind (others need Python objects).
_POLICY_KWARGS = {
    "net_arch": "net_arch",
    "log_std_init": _REAL,
    "ortho_init": _BOOL,
    "use_sde": _BOOL,
    "full_std": _BOOL,
    "use_expln": _BOOL,
    "squash_output": _BOOL,
    "share_features_extractor": _BOOL,
    "normalize_images": _BOOL,
    "n_critics": _INT,
    "clip_mean": _REAL,
}


def _check_value(name: str, value: Any, kind: str, low, high, low_open: bool) -> None:
    """One keyword argument against its kind and range; ValueError naming it."""
    where = ""
    if low is not None or high is not None:
        left = "(" if low_open else "["
        lo = "-inf" if low is None else low
        where = f" in {left}{lo}, {'inf' if high is None else high}]"
    bad = ValueError(f"--hyperparams {name} must be {kind}{where}, got {value!r}")
    if kind == _BOOL:
        if not isinstance(value, bool):
            raise bad
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise bad
    if kind == _INT and not isinstance(value, int):
        raise bad
    if isinstance(value, float) and not math.isfinite(value):
        raise bad
    if low is not None and (value < low or (low_open and value == low)):
        raise bad
    if high is not None and value > high:
        raise bad


def _check_layers(name: str, value: Any) -> None:
    if not (
        isinstance(value, list)
        and all(
            isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 1_000_000 for n in value
        )
    ):
        raise ValueError(
            f"--hyperparams {name} must be a list of layer sizes (integers in [1, 1000000]), "
            f"e.g. [64, 64]; got {value!r}"
        )


def check_policy_kwargs(algo: str, policy: str, value: Any) -> None:
    """policy_kwargs: a JSON object of the policy class's JSON-expressible arguments."""
    if not isinstance(value, dict):
        raise ValueError(f"--hyperparams policy_kwargs must be a JSON object, got {value!r}")
    policy_class = algorithm_class(algo).policy_aliases.get(policy)
    accepted = set(inspect.signature(policy_class.__init__).parameters) if policy_class else set()
    for key, item in value.items():
        if key not in accepted:
            raise ValueError(
                f"--hyperparams policy_kwargs: {key!r} is not an argument of the {algo} "
                f"{policy}; accepted: {', '.join(k for k in _POLICY_KWARGS if k in accepted)}"
            )
        kind = _POLICY_KWARGS.get(key)
        if kind is None:
            raise ValueError(
                f"--hyperparams policy_kwargs {key!r} needs a Python object and cannot be given "
                "as JSON; build the model in Python to set it"
            )
        if kind == "net_arch":
            if isinstance(item, dict):
                for part, layers in item.items():
                    if part not in ("pi", "vf", "qf"):
                        raise ValueError(
                            "--hyperparams policy_kwargs net_arch keys are pi, vf, qf; "
                            f"got {part!r}"
                        )
                    _check_layers(f"policy_kwargs net_arch {part}", layers)
            else:
                _check_layers("policy_kwargs net_arch", item)
        elif kind == _INT:
            _check_value(f"policy_kwargs {key}", item, kind, 1, 100, False)
        else:
            _check_value(f"policy_kwargs {key}", item, kind, None, None, False)


def check_hyperparams(algo: str, hyperparams: dict[str, Any], policy: str = "MlpPolicy") -> None:
    """Check the --hyperparams of `algo` before anything is built.

    A key must be a keyword argument of the SB3 algorithm's constructor (read from its
    signature), or rl-zoo3's noise_type / noise_std for the off-policy algorithms; the common
    ones are range-checked (`HYPERPARAM_RANGES`), ``train_freq``, ``ent_coef``,
    ``target_entropy``, ``clip_range_vf`` and ``target_kl`` by their own rules.
    """
    cls = algorithm_class(algo)
    accepted = set(inspect.signature(cls.__init__).parameters) - {"self"}
    if algo in ("sac", "td3"):
        accepted |= set(NOISE_KEYS)
    for key, value in hyperparams.items():
        if key in _NOT_FROM_JSON and key in accepted | {"policy", "env"}:
            raise ValueError(f"--hyperparams cannot set {key!r}: {_NOT_FROM_JSON[key]}")
        if key not in accepted:
            close = difflib.get_close_matches(key, sorted(accepted), n=2)
            hint = f" (did you mean {' or '.join(close)}?)" if close else ""
            raise ValueError(
                f"--hyperparams: {key!r} is not a keyword argument of SB3's {cls.__name__}{hint}"
            )
        if key in HYPERPARAM_RANGES:
            _check_value(key, value, *HYPERPARAM_RANGES[key])
        elif key == "policy_kwargs":
            check_policy_kwargs(algo, policy, value)
        elif key == "train_freq":
            ok = isinstance(value, int) and not isinstance(value, bool) and value >= 1
            ok = ok or (
                isinstance(value, list)
                and len(value) == 2
                and isinstance(value[0], int)
                and not isinstance(value[0], bool)
                and value[0] >= 1
                and value[1] in ("step", "episode")
            )
            if not ok:
                raise ValueError(
                    f'--hyperparams train_freq must be an integer >= 1 or [n, "step" | '
                    f'"episode"], got {value!r}'
                )
        elif key == "ent_coef" and algo == "sac":
            if not (
                isinstance(value, str) and re.fullmatch(r"auto(_\d+(\.\d*)?(e-?\d+)?)?", value)
            ):
                _check_value(key, value, _REAL, 0.0, None, False)
        elif key == "ent_coef":
            _check_value(key, value, _REAL, 0.0, None, False)
        elif key == "target_entropy":
            if value != "auto":
                _check_value(key, value, _REAL, None, None, False)
        elif key in ("clip_range_vf", "target_kl"):
            if value is not None:
                _check_value(key, value, _REAL, 0.0, None, True)
        elif key == "noise_type":
            if value != "normal":
                raise ValueError(f"--hyperparams noise_type must be 'normal', got {value!r}")
        elif key == "n_steps" and algo in ("sac", "td3"):
            _check_value(key, value, _INT, 1, 10**6, False)
