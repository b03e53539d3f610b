"""The feedback law the analytic-policy-gradient learner trains, and its `PolicyPredictor`.

`SwarmFeedbackLaw` (a `torch.nn.Module`) maps what the swarm envs observe to the control u^n
that every Brownian path receives, one agent at a time with the same weights (permutation
equivariant, and independent of N: a law trained at one N runs at any N with the same d):

    features of agent k at t_n (E = mean over the env's Brownian paths, as in the observation):
        e_k = E x_k - (1/N) sum_l E x_l        (the agent's offset from the swarm's centre)
        c   = (1/N) sum_l E x_l - xbar         (the centre's offset from the target)
        D_k = E (1/N) sum_l p(x_k, x_l)(x_l - x_k)   (the observed interaction drift)
        s   = t_n / T

    u_k = - a(s) c - b(s) e_k + w(s) D_k + h(e_k, c, D_k / drift_scale, s)

a, b, w are time-varying gains (one value per knot s_j = j / K, linear in between; K = m, the
episode's steps, by default, so every step has its own gains); h is a small tanh MLP shared by
the agents whose last layer starts at zero. At initialisation a = b = `initial_gain` and w = 0,
h = 0: the proportional law u_k = beta (xbar - E x_k) (`agent_envs.baselines.controllers`,
without its switch-off). The output is clipped to [-max_control, max_control] as the env clips
its action (`u = max_control * clip(action, -1, 1)`), so the law trained through the simulator
is exactly the law that acts in the env.

Why these features: for a symmetric kernel the interaction drift sums to zero over the agents,
so the swarm's centre moves with the mean control only (a scalar linear-quadratic problem whose
optimal feedback is linear in c with a time-varying gain), while the offsets e_k contract under
the interaction (`eq:dyn_matrix`); D_k = (L(x) x)_k is that contraction, observed.

`SwarmFeedbackPolicy` wraps a law as an SB3 `PolicyPredictor` (``predict(obs, state,
episode_start, deterministic) -> (action, state)``) for the Gymnasium env `agent_envs/Swarm-v0`
(one observation or a VecEnv batch, N read from the observation's length) and the PettingZoo
env `agent_envs.swarm_v0` (the N agents' rows stacked, or `act(dict)` with all agents).
Weights are saved as a torch ``state_dict`` next to a JSON description of the law, and loaded
with ``torch.load(weights_only=True)``: nothing is unpickled (`save_law`, `load_law`).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from agent_envs.envs.observation import agent_observation_size
from agent_envs.training.storage import RunManifest
from agent_envs.validation import check_int, check_positive

#: the file names of a saved law (weights and its description) in a run folder
LAW_WEIGHTS = "apg_law.pt"
LAW_DESCRIPTION = "apg_law.json"
BEST_LAW = "best_apg_law.pt"
FINAL_LAW = "final_apg_law.pt"
_DESCRIPTION_FORMAT = "agent-envs apg feedback law"


@dataclass(frozen=True)
class LawSpec:
    """What a `SwarmFeedbackLaw` is built from (saved as JSON next to its weights).

    Attributes:
        dim: d, the space dimension (1 <= d <= 3 in practice; any d >= 1 accepted).
        n_knots: K >= 1, gain knots at s = j / K (default 50 = the paper's m).
        hidden: width of the shared MLP h (0: the linear law alone), 0 <= hidden <= 1024.
        max_control: the env's bound on |u| per coordinate, > 0.
        initial_gain: a = b at initialisation (the proportional law's beta), >= 0.
        drift_scale: D_k is divided by it before entering h (> 0).
    """

    dim: int = 1
    n_knots: int = 50
    hidden: int = 16
    max_control: float = 25.0
    initial_gain: float = 12.0
    drift_scale: float = 10.0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "dim", check_int("dim", self.dim, 1, 1000))
        set_(self, "n_knots", check_int("n_knots", self.n_knots, 1, 100_000))
        set_(self, "hidden", check_int("hidden", self.hidden, 0, 1024))
        set_(self, "max_control", check_positive("max_control", self.max_control))
        if not isinstance(self.initial_gain, (int, float)) or isinstance(self.initial_gain, bool):
            raise TypeError(f"initial_gain must be a real number, got {self.initial_gain!r}")
        if not (math.isfinite(self.initial_gain) and 0 <= self.initial_gain <= 1e6):
            raise ValueError(f"initial_gain must be in [0, 1e6], got {self.initial_gain}")
        set_(self, "initial_gain", float(self.initial_gain))
        set_(self, "drift_scale", check_positive("drift_scale", self.drift_scale))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LawSpec:
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"unknown LawSpec field(s) {unknown}; expected {sorted(names)}")
        return cls(**dict(data))


class SwarmFeedbackLaw(nn.Module):
    """The per-agent feedback law of the module docstring (float64 parameters).

    `seed` seeds the MLP's first layer (uniform in +-1/sqrt(fan in), torch's default range) with
    a generator of its own: building a law never reads or advances torch's global generator.
    """

    def __init__(self, spec: LawSpec, seed: int = 0) -> None:
        super().__init__()
        if not isinstance(spec, LawSpec):
            raise TypeError(f"spec must be a LawSpec, got {type(spec).__name__}")
        self.spec = spec
        k, f64 = spec.n_knots, torch.float64
        self.centre_gain = nn.Parameter(torch.full((k,), spec.initial_gain, dtype=f64))
        self.offset_gain = nn.Parameter(torch.full((k,), spec.initial_gain, dtype=f64))
        self.drift_gain = nn.Parameter(torch.zeros(k, dtype=f64))
        self.mlp: nn.Module | None = None
        if spec.hidden > 0:
            d, h = spec.dim, spec.hidden
            first = nn.Linear(3 * d + 1, h, dtype=f64)
            generator = torch.Generator().manual_seed(int(seed))
            bound = 1.0 / math.sqrt(3 * d + 1)
            with torch.no_grad():
                first.weight.uniform_(-bound, bound, generator=generator)
                first.bias.uniform_(-bound, bound, generator=generator)
            last = nn.Linear(h, d, dtype=f64)
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)
            self.mlp = nn.Sequential(first, nn.Tanh(), last)

    def gains(self, time_fraction: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """(a, b, w) at s = t/T, linear between the knots s_j = j / K; shape of s."""
        k = self.spec.n_knots
        pos = torch.clamp(time_fraction * k, 0.0, float(k - 1))
        low = torch.clamp(torch.floor(pos).long(), 0, k - 1)
        high = torch.clamp(low + 1, max=k - 1)
        frac = pos - low.to(pos.dtype)
        out = []
        for table in (self.centre_gain, self.offset_gain, self.drift_gain):
            out.append(table[low] * (1.0 - frac) + table[high] * frac)
        return tuple(out)

    def forward(
        self,
        positions: torch.Tensor,
        drift: torch.Tensor,
        target: torch.Tensor,
        time_fraction: torch.Tensor,
    ) -> torch.Tensor:
        """u (..., N, d) from path-mean positions and drift (..., N, d), target (..., d) and
        t/T (...); clipped to [-max_control, max_control]."""
        centre = positions.mean(dim=-2, keepdim=True)  # (..., 1, d)
        offset = positions - centre
        to_target = centre - target[..., None, :]
        a, b, w = (g[..., None, None] for g in self.gains(time_fraction))
        u = -a * to_target - b * offset + w * drift
        if self.mlp is not None:
            s = torch.broadcast_to(time_fraction[..., None, None], (*offset.shape[:-1], 1))
            feats = torch.cat(
                [
                    offset,
                    torch.broadcast_to(to_target, offset.shape),
                    drift / self.spec.drift_scale,
                    s.to(offset.dtype),
                ],
                dim=-1,
            )
            u = u + self.mlp(feats)
        bound = self.spec.max_control
        return torch.clamp(u, -bound, bound)


# ------------------------------------------------------------------------------ save and load


def save_law(law: SwarmFeedbackLaw, path: str | os.PathLike) -> None:
    """Write the weights (``state_dict``, tensors only) to `path` (a temporary path is fine)."""
    torch.save({k: v.detach().cpu() for k, v in law.state_dict().items()}, path)


def describe_law(spec: LawSpec) -> dict[str, Any]:
    return {"format": _DESCRIPTION_FORMAT, "version": 1, "spec": asdict(spec)}


def read_spec(path: str | os.PathLike) -> LawSpec:
    """The `LawSpec` of a law description JSON (ValueError naming the file when malformed)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: not a readable apg law description ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != _DESCRIPTION_FORMAT:
        raise ValueError(f"{path}: not an apg law description (format {_DESCRIPTION_FORMAT!r})")
    return LawSpec.from_dict(data.get("spec", {}))


def load_law(weights: str | os.PathLike, spec: LawSpec | None = None) -> SwarmFeedbackLaw:
    """A law from its weights file; the spec from `spec` or the description beside it.

    The weights are read with ``torch.load(weights_only=True)`` (no pickle of arbitrary
    objects). Raises ValueError naming the file when it is missing, unreadable or does not
    fit the spec.
    """
    weights = Path(weights)
    if not weights.is_file():
        raise ValueError(f"weights {weights}: no such file")
    if spec is None:
        spec = read_spec(weights.parent / LAW_DESCRIPTION)
    law = SwarmFeedbackLaw(spec)
    try:
        state = torch.load(weights, map_location="cpu", weights_only=True)
        law.load_state_dict(state)
    except Exception as exc:  # torch raises RuntimeError/UnpicklingError/EOFError...
        raise ValueError(f"weights {weights}: cannot load an apg law ({exc})") from None
    law.eval()
    return law


# ------------------------------------------------------------------------------ the predictor


class SwarmFeedbackPolicy:
    """A `SwarmFeedbackLaw` as an SB3 `PolicyPredictor` on both swarm envs (module docstring).

    Observations (layouts of `agent_envs.envs.observation`), N read from their shape:

    - Gymnasium: (2Nd + d + 1,) or a batch (B, 2Nd + d + 1) -> actions (Nd,) or (B, Nd);
    - PettingZoo: the rows of all N agents of one swarm (N, 3d + 1), or (B, N, 3d + 1) ->
      actions (N, d) or (B, N, d); a dict {agent: row} with every agent -> `act`.

    Actions are ``clip(u / max_control, -1, 1)`` as float32 (the env multiplies by
    `max_control` again). Stateless: `state` is returned as given.
    """

    def __init__(self, law: SwarmFeedbackLaw) -> None:
        if not isinstance(law, SwarmFeedbackLaw):
            raise TypeError(f"law must be a SwarmFeedbackLaw, got {type(law).__name__}")
        self.law = law.eval()
        self.dim = law.spec.dim
        self.max_control = law.spec.max_control

    def _split(self, obs: np.ndarray) -> tuple[np.ndarray, ...]:
        d = self.dim
        width = obs.shape[-1]
        if obs.ndim in (2, 3) and width == agent_observation_size(d) and obs.shape[-2] > 1:
            rows = obs if obs.ndim == 3 else obs[None]
            return (
                rows[..., :d],
                rows[..., d : 2 * d],
                rows[..., 0, 2 * d : 3 * d],
                rows[..., 0, -1],
                obs.ndim == 2,
                True,
            )
        if obs.ndim not in (1, 2) or (width - d - 1) % (2 * d) or width < 3 * d + 1:
            raise ValueError(
                f"observation must be a Gymnasium observation (2Nd + d + 1,) / (B, 2Nd + d + 1) "
                f"or the PettingZoo rows of one swarm (N, 3d + 1) / (B, N, 3d + 1) for d = {d}; "
                f"got shape {obs.shape}"
            )
        batch = obs[None] if obs.ndim == 1 else obs
        n = (width - d - 1) // (2 * d)
        nd = n * d
        lead = batch.shape[0]
        return (
            batch[:, :nd].reshape(lead, n, d),
            batch[:, nd : 2 * nd].reshape(lead, n, d),
            batch[:, 2 * nd : 2 * nd + d],
            batch[:, -1],
            obs.ndim == 1,
            False,
        )

    def control(self, observation: Any) -> np.ndarray:
        """u (..., N, d) float64 for observations (see the class docstring)."""
        obs = np.asarray(observation, dtype=np.float64)
        if obs.size and not np.all(np.isfinite(obs)):
            raise ValueError("observation must be finite")
        positions, drift, target, time_fraction, squeeze, _ = self._split(obs)
        with torch.no_grad():
            u = self.law(
                torch.as_tensor(positions),
                torch.as_tensor(drift),
                torch.as_tensor(target),
                torch.as_tensor(time_fraction),
            ).numpy()
        return u[0] if squeeze else u

    def predict(
        self,
        observation: Any,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3 `PolicyPredictor.predict` (class docstring); `deterministic` is ignored (the law
        is deterministic)."""
        if isinstance(observation, Mapping):
            return self.act(observation), state
        obs = np.asarray(observation, dtype=np.float64)
        *_, per_agent = self._split(obs)
        u = self.control(obs)
        action = np.clip(u / self.max_control, -1.0, 1.0).astype(np.float32)
        if not per_agent:
            action = action.reshape(*action.shape[:-2], -1)
        return action, state

    def act(self, observations: Mapping[str, Any]) -> dict[str, np.ndarray]:
        """PettingZoo parallel env: {agent: action (d,)} from the rows of all the swarm's agents."""
        agents = list(observations)
        if not agents:
            return {}
        rows = np.stack([np.asarray(observations[a], dtype=np.float64) for a in agents])
        if rows.shape[-1] != agent_observation_size(self.dim):
            raise ValueError(
                f"per-agent observations must have shape ({agent_observation_size(self.dim)},) "
                f"for d = {self.dim}, got {rows.shape[1:]}"
            )
        if len(agents) == 1:  # one agent: its row is also the Gymnasium observation
            actions, _ = self.predict(rows[0])
            return {agents[0]: actions.reshape(self.dim)}
        actions, _ = self.predict(rows)
        return {a: actions[i] for i, a in enumerate(agents)}

    def __repr__(self) -> str:
        s = self.law.spec
        return f"SwarmFeedbackPolicy(d={s.dim}, knots={s.n_knots}, hidden={s.hidden})"


# ------------------------------------------------------------------------------ runs


def is_apg_run(path: str | os.PathLike) -> bool:
    """True when `path` is an apg run folder or an apg weights file beside its description."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    return (folder / LAW_DESCRIPTION).is_file() and (path.is_dir() or path.suffix == ".pt")


def load_apg_policy(path: str | os.PathLike, which: str = "best") -> SwarmFeedbackPolicy:
    """The `PolicyPredictor` of an apg run: a run folder (its best or final law) or a weights
    file (``*.pt`` beside ``apg_law.json``).

    The weights must match the run's manifest when the folder has one (as SB3 statistics are
    checked); ValueError naming the path otherwise.
    """
    if which not in ("best", "final"):
        raise ValueError(f"which must be 'best' or 'final', got {which!r}")
    path = Path(path)
    weights = path / (BEST_LAW if which == "best" else FINAL_LAW) if path.is_dir() else path
    if path.is_dir() and which == "best" and not weights.is_file():
        weights = path / FINAL_LAW
    manifest = RunManifest(weights.parent)
    if manifest.exists():
        problem = manifest.problem(weights)
        if problem is not None:
            raise ValueError(f"apg policy {path}: {problem}")
    return SwarmFeedbackPolicy(load_law(weights))


__all__ = [
    "BEST_LAW",
    "FINAL_LAW",
    "LAW_DESCRIPTION",
    "LawSpec",
    "SwarmFeedbackLaw",
    "SwarmFeedbackPolicy",
    "describe_law",
    "is_apg_run",
    "load_apg_policy",
    "load_law",
    "read_spec",
    "save_law",
]
