"""The reference check of the native vector env's compiled prologue and epilogue
(`agent_envs.native.step`, the compiled path "step").

`same_as_numpy` is registered with the loader (`agent_envs.native.register_check`) when this
module is imported; the loader runs it when the path first loads, when a native vector env
that can use it is made. It checks the module against the numpy calls it replaces, on fixed
random data of several shapes: the controls ("agents" and "common" bases), running costs and
right-hand sides of `prologue` against `controls_from_actions`, `mean_running_cost` and F =
L(x) x + u; the path means, observations and divergence flags of `epilogue` against
`arrays.mean_axis`, `global_observation` and `advance_paths`'s checks, every value bit for bit
(signed zeros included, values the clip cuts), on read-only states as the env passes them.
Where numba is missing or switched off (``AGENT_ENVS_NUMBA=0``) the path is off; where a value
differs (a numpy that sums in another order), or the module does not compile, off with a
warning; the env then steps with its numpy calls.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agent_envs import arrays, native
from agent_envs.envs.episode import mean_running_cost
from agent_envs.envs.interface import controls_from_actions
from agent_envs.envs.observation import global_observation, observation_space
from agent_envs.simulator import diverged_paths

#: (B, P, N, d) of the load check: one and several paths, N below, at and above numpy's
#: pairwise blocks (8, 128), d = 1, 2, 3 and 9 (a pairwise sum over the coordinates)
CHECK_SHAPES = ((2, 1, 100, 1), (2, 20, 100, 1), (2, 3, 5, 2), (1, 2, 130, 3), (1, 1, 300, 2),
                (2, 1, 1, 1), (1, 9, 17, 9), (1, 1, 8, 1), (1, 1, 128, 2))  # fmt: skip


def compiled_step() -> Any:
    """``native.loaded("step")``: the compiled module (`load_compiled_step` must have answered
    True)."""
    return native.loaded("step")


def load_compiled_step() -> bool:
    """``native.available("step")``: whether the native vector env may take its compiled
    prologue and epilogue (module docstring); loads and checks them on the first call."""
    return native.available("step")


def _same_bits(a: np.ndarray, b: Any) -> bool:
    b = np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def same_as_numpy(
    module: Any, shapes: tuple[tuple[int, int, int, int], ...] = CHECK_SHAPES
) -> bool:
    """Whether `module.prologue` and `module.epilogue` give the numpy step's values bit for bit
    on fixed random data of `shapes` (B, P, N, d), actions float32 and float64, states over
    six orders of magnitude, and one env beyond the divergence threshold."""
    rng = np.random.default_rng(20261127)
    for b, p, n, d in shapes:
        scale = 10.0 ** rng.uniform(-3, 3, (b, p, n, d))
        x = rng.standard_normal((b, p, n, d)) * scale
        drift = rng.standard_normal((b, p, n, d)) * scale
        x.flat[:2] = (-0.0, 0.0)  # signed zeros, and below, means the clip cuts
        drift.flat[-2:] = (-0.0, 0.0)
        x.flat[2::7] *= 1e4
        drift.flat[3::5] *= 1e3
        # read-only, as the env passes its state and drift (numba compiles read-only arrays
        # apart: this checks the machine code the env runs)
        x.flags.writeable = False
        drift.flags.writeable = False
        targets = rng.standard_normal((b, d))
        for dtype in (np.float32, np.float64):
            actions = rng.uniform(-2.0, 2.0, (b, n, d)).astype(dtype)
            actions[0, 0, 0] = -0.0
            controls, costs, rhs = np.empty((b, n, d)), np.empty(b), np.empty(x.shape)
            # the "agents" basis (a row per agent) and the "common" one (one row for all)
            for given, basis in ((actions, "agents"), (actions[:, :1].copy(), "common")):
                if not module.prologue(given, 25.0, x, drift, targets, 0.37, controls, costs,
                                       rhs):  # fmt: skip
                    return False
                want_u = controls_from_actions(given.astype(np.float64), basis, 25.0, n)
                if not (
                    _same_bits(controls, want_u)
                    and _same_bits(costs, mean_running_cost(x, want_u, targets, 0.37))
                    and _same_bits(rhs, drift + want_u[:, None])
                ):
                    return False
        bad = np.array(actions)
        bad[-1, -1, -1] = np.nan
        if module.prologue(bad, 25.0, x, drift, targets, 0.37, controls, costs, rhs):
            return False
        x_next = np.array(x)
        x_next[-1, -1, -1, -1] = 1e7  # beyond the threshold below: that env diverged
        x_next.flags.writeable = False
        fractions = rng.uniform(0.0, 1.0, b)
        fractions[0] = -0.0  # a tie with the time slot's bound 0.0: np.clip gives +0.0
        for threshold in (1e6, np.inf):
            # bounds the means cross (positions up to 1e7, drift up to 3e6): the clip cuts
            space = observation_space(n, d, min(threshold, 1e6), 1e5)
            means = np.empty((b, n, d)), np.empty((b, n, d))
            obs = np.empty((b, *space.shape), dtype=np.float32)
            flags = np.empty(b, dtype=np.bool_)
            module.epilogue(x_next, drift, threshold, targets, fractions, space.low, space.high,
                            True, *means, obs, flags)  # fmt: skip
            want_x, want_f = arrays.mean_axis(x_next, -3), arrays.mean_axis(drift, -3)
            want_obs = global_observation(want_x, want_f, targets, fractions, space)
            want_flags = np.any(diverged_paths(x_next, threshold), axis=-1) | ~np.all(
                np.isfinite(want_f), axis=(-2, -1)
            )
            if not (
                _same_bits(means[0], want_x)
                and _same_bits(means[1], want_f)
                and _same_bits(obs, want_obs)
                and _same_bits(flags, want_flags)
            ):
                return False
    return True


native.register_check("step", same_as_numpy, "the native vector env steps with numpy calls")
