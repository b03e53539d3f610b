"""One helper the tests share: the cost of one seeded episode of a policy."""

from __future__ import annotations

from typing import Any


def episode_cost(policy: Any, env: Any, seed: int) -> float:
    """Minus the summed rewards of one episode of `policy` on the Gymnasium `env` reset with
    `seed` (the discrete cost functional on the env's paths)."""
    obs, _ = env.reset(seed=seed)
    total, done = 0.0, False
    while not done:
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, _ = env.step(action)
        total -= reward
        done = terminated or truncated
    return total
