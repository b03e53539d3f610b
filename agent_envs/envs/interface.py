"""What a learner sees and moves: the observation layouts, the action basis, the agent reward.

These are env kwargs of both swarm envs (`EpisodeConfig` fields). They change the interface,
never the dynamics, the cost or the random draws: an episode with the same seed and the same
controls u^n has the same states and the same rewards under every option, so a policy trained
with one option is compared with a reference controller on another on equal terms.

Why they exist (issue "SB3 learners that learn at the paper's scale", docs/env-options.md): in
the stiff swarm the interaction collapses the agents onto their centre within a few steps, and
only the common mode of the controls moves the centre; in the agents' own coordinates a learner
must find that one direction among N d. In the centre-and-differences basis below it is one
coordinate.

**The modes of the agent axis.** For N agents, the basis of R^N ::

    e_0 = (1, ..., 1),   e_j = (1, ..., 1, -j, 0, ..., 0) / sqrt(j (j + 1)),  j = 1 .. N - 1

(j ones, then -j at index j: the Helmert differences, orthonormal and orthogonal to e_0). The
coordinates of a vector v (N,) in it are ``m_0 = mean(v)`` and ``m_j = <e_j, v>``;
`to_modes` computes them and `from_modes` is its inverse ``v = m_0 e_0 + sum_j m_j e_j``, both
matrix-free in O(N) with running sums (per spatial coordinate, batched over leading axes, numpy
or torch). So mode 0 of the positions is the swarm's centre and mode 0 of the controls is the
control every agent shares.

**Action bases** (`ACTION_BASES`, Gymnasium env and native vector env):

- ``"agents"`` (default): u_k = max_control * clip(a_k, -1, 1), the action in agent order.
- ``"modes"``: u = max_control * clip(from_modes(clip(a, -1, 1)), -1, 1): a_0 in [-1, 1] moves
  every agent by the same control (the whole range [-max_control, max_control]), a_j the j-th
  difference mode. The map is invertible, so every control of |u_k| <= max_control whose
  coordinates fit the box is reachable; in particular any common control plus differences of
  Euclidean norm <= max_control (the box holds the ball of radius max_control, since e_1 ..
  e_{N-1} are orthonormal) as long as each agent's sum stays within the bound (the control is
  clipped agent by agent after the change of basis).
- ``"common"``: the action is mode 0 alone, d entries: u_k = max_control * clip(a, -1, 1) for
  every agent (one control broadcast to the swarm). This restricts the controls: no agent can
  be steered apart from the others. docs/env-options.md measures what that costs (the optimal
  control's own common mode, applied alone).

**Observation layouts** (`OBSERVATIONS` for the Gymnasium env, `AGENT_OBSERVATIONS` for one
PettingZoo agent; `agent_envs.envs.observation` builds them). Time t / T is always last.

- ``"absolute"`` (default): E x, E drift, target xbar, t / T.
- ``"relative"``: E x - xbar in place of E x (same length, same slices).
- ``"modes"`` (Gymnasium): to_modes(E x - xbar) and to_modes(E drift) in place of E x and
  E drift: slice 0 (d entries) is the centre's offset from the target.
- ``"summary"`` (Gymnasium, 3 d + 1 entries): the centre's offset c - xbar, the spread
  sqrt(mean_k (x_k - c)^2) per coordinate, xbar, t / T. It holds no agent's own position, so a
  policy on it cannot feed back on single agents (the optimum's per-agent part is small in the
  stiff regime; docs/env-options.md measures it).
- ``"swarm"`` (PettingZoo, 5 d + 1 entries): the ``"relative"`` row of agent k with the swarm's
  centre offset c - xbar and spread inserted before t / T.
- ``"local"`` (PettingZoo, (K + 1)(d + 1) entries, K the kwarg ``neighbours``, default
  `DEFAULT_NEIGHBOURS`, in [1, `MAX_NEIGHBOURS`]; only with this layout): agent k's own offset
  E x_k - xbar, its K nearest neighbours' offsets E x_l - E x_k and a mask (zeros and mask 0
  where N - 1 < K), t / T; no global statistic (`agent_envs.envs.local_observation`: the
  ranking, ties, the communication graph and its cost). The Gymnasium env has no per-agent
  rows, so it does not take it.

**Agent reward** (`AGENT_REWARDS`, PettingZoo env): ``"own"`` (default) gives agent k
-tau/N (|x_k - xbar|^2 + gamma |u_k|^2) (they add up to the swarm's reward); ``"team"`` gives
every agent the swarm's reward -tau c(x^n, u^n), so that each one is credited with what moves
the cost: the centre, which no single agent moves by more than O(1/N).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agent_envs import arrays

#: Observation layouts of `agent_envs/Swarm-v0` (and its native vector env).
OBSERVATIONS = ("absolute", "relative", "modes", "summary")
#: Observation layouts of one agent of `agent_envs.swarm_v0`.
AGENT_OBSERVATIONS = ("absolute", "relative", "swarm", "local")
#: K of the ``"local"`` layout when the kwarg ``neighbours`` is not given, and its largest value.
DEFAULT_NEIGHBOURS = 6
MAX_NEIGHBOURS = 1024
#: Action bases of `agent_envs/Swarm-v0` (the PettingZoo env acts per agent: "agents" only).
ACTION_BASES = ("agents", "modes", "common")
#: Reward of each agent of `agent_envs.swarm_v0` (the Gymnasium env has one reward).
AGENT_REWARDS = ("own", "team")

#: Every accepted value of each option (each env accepts its own subset; see `check_options`).
OPTION_VALUES: dict[str, tuple[str, ...]] = {
    "observation": tuple(dict.fromkeys((*OBSERVATIONS, *AGENT_OBSERVATIONS))),
    "action_basis": ACTION_BASES,
    "agent_reward": AGENT_REWARDS,
}

#: What each env kind accepts: "gymnasium" (Swarm-v0, its vector env) or "pettingzoo".
ENV_KIND_VALUES: dict[str, dict[str, tuple[str, ...]]] = {
    "gymnasium": {
        "observation": OBSERVATIONS,
        "action_basis": ACTION_BASES,
        "agent_reward": ("own",),
    },
    "pettingzoo": {
        "observation": AGENT_OBSERVATIONS,
        "action_basis": ("agents",),
        "agent_reward": AGENT_REWARDS,
    },
}


def check_option(name: str, value: Any) -> str:
    """`value` if it is one of `OPTION_VALUES[name]`; TypeError/ValueError naming `name`."""
    if not isinstance(value, str):
        raise TypeError(
            f"{name} must be a str, one of {', '.join(OPTION_VALUES[name])}; got "
            f"{type(value).__name__}"
        )
    if value not in OPTION_VALUES[name]:
        raise ValueError(f"{name} must be one of {', '.join(OPTION_VALUES[name])}; got {value!r}")
    return value


def check_env_options(kind: str, **options: str) -> None:
    """ValueError naming the option when `kind`'s env does not take its value.

    E.g. ``action_basis="modes"`` on the PettingZoo env, where each agent acts for itself.
    """
    accepted = ENV_KIND_VALUES[kind]
    for name, value in options.items():
        if value not in accepted[name]:
            env = "agent_envs/Swarm-v0" if kind == "gymnasium" else "agent_envs.swarm_v0"
            raise ValueError(
                f"{name}={value!r} is not an option of {env}; it takes "
                f"{', '.join(repr(v) for v in accepted[name])}"
            )


# ------------------------------------------------------------------------------ the modes


def _cumsum(x: Any, axis: int) -> Any:
    if isinstance(x, np.ndarray):
        return np.cumsum(x, axis=axis)
    import torch

    return torch.cumsum(x, dim=axis)


def _mode_scales(n: int, like: Any) -> Any:
    """sqrt(j (j + 1)) for j = 1 .. n - 1, shape (n - 1, 1), in the library and dtype of like."""
    j = np.arange(1, n, dtype=np.float64)
    scales = np.sqrt(j * (j + 1.0))[:, None]
    return arrays.asarray(scales, like=like)


def to_modes(v: Any) -> Any:
    """Coordinates of v in the basis e_0 .. e_{N-1} (module docstring): (..., N, d) -> same.

    m_0 = mean_k v_k, m_j = (v_0 + ... + v_{j-1} - j v_j) / sqrt(j (j + 1)). The mean is the
    running sum's last entry / N, so every row of a batch gives the same bits as alone.
    """
    n = v.shape[-2]
    partial = _cumsum(v, axis=-2)
    xp = arrays.namespace(v)
    mean = partial[..., -1:, :] / n
    if n == 1:
        return mean
    j = arrays.asarray(np.arange(1, n, dtype=np.float64)[:, None], like=v)
    differences = (partial[..., :-1, :] - j * v[..., 1:, :]) / _mode_scales(n, v)
    return xp.concat([mean, differences], axis=-2)


def from_modes(m: Any) -> Any:
    """v = m_0 e_0 + sum_j m_j e_j, the inverse of `to_modes`: (..., N, d) -> same.

    v_k = m_0 + sum_{j > k} m_j / sqrt(j (j + 1)) - k m_k / sqrt(k (k + 1)) (the last term for
    k >= 1), from one running sum from the end.
    """
    n = m.shape[-2]
    xp = arrays.namespace(m)
    if n == 1:
        return m * 1.0
    w = m[..., 1:, :] / _mode_scales(n, m)  # w_j, j = 1 .. N - 1
    # tail_k = sum_{j > k} w_j for k = 0 .. N - 1 (tail_{N-1} = 0)
    total = _cumsum(xp.flip(w, axis=-2), axis=-2)
    tail = xp.concat([xp.flip(total, axis=-2), xp.zeros_like(m[..., :1, :])], axis=-2)
    j = arrays.asarray(np.arange(1, n, dtype=np.float64)[:, None], like=m)
    own = xp.concat([xp.zeros_like(m[..., :1, :]), j * w], axis=-2)
    return m[..., :1, :] + tail - own


def action_rows(basis: str, n_agents: int) -> int:
    """Rows of d entries in one action: 1 for "common", N otherwise."""
    return 1 if basis == "common" else n_agents


def controls_from_actions(
    actions: Any, basis: str, max_control: float, n_agents: int | None = None
) -> Any:
    """u (..., N, d) from actions (..., rows, d) in the action basis (module docstring).

    "agents": max_control * clip(a, -1, 1); "modes": max_control * clip(from_modes(clip(a, -1,
    1)), -1, 1); "common": max_control * clip(a, -1, 1) (..., 1, d) repeated for the
    `n_agents` agents. numpy arrays or torch tensors.
    """
    check_option("action_basis", basis)
    xp = arrays.namespace(actions)
    a = xp.clip(actions, -1.0, 1.0)
    if basis == "modes":
        a = xp.clip(from_modes(a), -1.0, 1.0)
    elif basis == "common":
        if n_agents is None:
            raise ValueError("n_agents is needed for action_basis='common'")
        if a.shape[-2] != 1:
            raise ValueError(
                f"actions for action_basis='common' have shape (..., 1, d), got {tuple(a.shape)}"
            )
        a = xp.broadcast_to(a, (*a.shape[:-2], n_agents, a.shape[-1]))
    return max_control * a


def actions_from_controls(controls: Any, basis: str, max_control: float) -> np.ndarray:
    """The action that applies u (..., N, d) in the action basis, clipped to [-1, 1].

    u is first clipped to the control bound agent by agent (what the "agents" basis applies),
    then expressed in the basis: u / max_control ("agents"), to_modes(u) / max_control
    ("modes": the env then applies exactly the clipped u whenever its coordinates fit the box;
    a difference coordinate can reach about 2, and is clipped), or the agents' mean control /
    max_control, (..., 1, d) ("common": the part of u it can apply). numpy, float64.
    """
    check_option("action_basis", basis)
    u = np.clip(np.asarray(controls, dtype=np.float64) / max_control, -1.0, 1.0)
    if basis == "modes":
        u = to_modes(u)
    elif basis == "common":
        u = u.mean(axis=-2, keepdims=True)
    return np.clip(u, -1.0, 1.0)


def swarm_summary(mean_positions: Any, target: Any) -> tuple[Any, Any]:
    """(c - xbar, spread): the centre's offset from the target and the per-coordinate spread.

    mean_positions (..., N, d), target (..., d) -> two (..., d) arrays; c = mean_k x_k (as
    `to_modes` takes it) and spread = sqrt(mean_k (x_k - c)^2).
    """
    xp = arrays.namespace(mean_positions)
    n = mean_positions.shape[-2]
    centre = _cumsum(mean_positions, axis=-2)[..., -1, :] / n
    offsets = mean_positions - centre[..., None, :]
    spread = xp.sqrt(_cumsum(offsets * offsets, axis=-2)[..., -1, :] / n)
    return centre - target, spread


def modes_bound(n_agents: int) -> float:
    """sqrt(N): |m_j| <= sqrt(N) max_k |v_k| for every mode j (Cauchy-Schwarz, |e_j| = 1)."""
    return math.sqrt(n_agents)


__all__ = [
    "ACTION_BASES",
    "AGENT_OBSERVATIONS",
    "AGENT_REWARDS",
    "DEFAULT_NEIGHBOURS",
    "ENV_KIND_VALUES",
    "MAX_NEIGHBOURS",
    "OBSERVATIONS",
    "OPTION_VALUES",
    "action_rows",
    "actions_from_controls",
    "check_env_options",
    "check_option",
    "controls_from_actions",
    "from_modes",
    "modes_bound",
    "swarm_summary",
    "to_modes",
]
