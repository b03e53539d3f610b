"""The native vector env's own arguments and per-call inputs, checked.

`SwarmVectorEnv` takes, besides the single env's keyword arguments (`EpisodeConfig`), its
batch's: `num_envs`, `autoreset_mode`, `device`/`backend`/`tensor_output` (where its arrays
live) and `num_threads`; and per call a seed per env and a (B, R d) or (B, R, d) batch of
actions. Each check here raises `TypeError`/`ValueError` naming the argument, in the order the
env's constructor has always checked them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

from agent_envs import arrays, native
from agent_envs.validation import check_seed, real_array

#: Autoreset modes the native env implements (Gymnasium's names).
AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)

SeedArg = int | Sequence[int | None] | None


def check_num_envs(num_envs: Any) -> int:
    """B, an int >= 1."""
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)):
        raise TypeError(f"num_envs must be an int >= 1, got {num_envs!r}")
    if num_envs < 1:
        raise ValueError(f"num_envs must be an int >= 1, got {num_envs}")
    return int(num_envs)


def check_render_mode(render_mode: Any) -> None:
    """The native env does not render: only None."""
    if render_mode is not None:
        raise ValueError(
            f"render_mode={render_mode!r}: the native vector env does not render; use "
            "gym.make_vec(..., vectorization_mode='sync', render_mode=...)"
        )


def resolve_arrays(
    backend: str | None, device: Any, tensor_output: Any, num_threads: Any
) -> tuple[str, Any, Any, int]:
    """(backend, array namespace, torch device or None, threads) of the env's arrays.

    `backend` None means numpy on "cpu" (or None), torch on any other device; a CUDA device
    must be visible to torch; `tensor_output` (a bool) needs torch; `num_threads` > 1 (at most
    numba's, `native.check_compiled_threads`) needs numpy.
    """
    if backend is None:
        backend = "numpy" if device in (None, "cpu") else "torch"
    xp, torch_device, _ = arrays.resolve(backend, device)
    if torch_device is not None and torch_device.type == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise ValueError(f"device={device!r}: torch sees no CUDA device here")
    if not isinstance(tensor_output, bool):
        raise TypeError(f"tensor_output must be a bool, got {tensor_output!r}")
    if tensor_output and backend != "torch":
        raise ValueError("tensor_output=True needs backend='torch' (or a torch device)")
    threads = native.check_compiled_threads(num_threads, "num_threads")
    if threads > 1 and backend != "numpy":
        raise ValueError(
            "num_threads > 1 needs the numpy backend (its compiled passes run on the "
            f"threads); backend={backend!r} runs torch's own"
        )
    return backend, xp, torch_device, threads


def check_autoreset_mode(autoreset_mode: Any) -> AutoresetMode:
    """Gymnasium's `AutoresetMode` (or its value) among `AUTORESET_MODES`."""
    try:
        mode = AutoresetMode(autoreset_mode)
    except ValueError:
        mode = None
    if mode not in AUTORESET_MODES:
        allowed = [m.value for m in AUTORESET_MODES]
        raise ValueError(f"autoreset_mode must be one of {allowed}, got {autoreset_mode!r}")
    return mode


def env_seeds(seed: SeedArg, num_envs: int) -> list[int | None]:
    """One seed (or None) per env: s, s + 1, ... for an int s; a list as given (one per env)."""
    if seed is None:
        return [None] * num_envs
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
        first = check_seed(seed)
        return [first + i for i in range(num_envs)]
    if not isinstance(seed, (list, tuple, np.ndarray)):
        raise TypeError(
            f"seed must be None, an integer >= 0 or a list of {num_envs} of them (one "
            f"per env), got {type(seed).__name__}"
        )
    seeds = [check_seed(s) for s in seed]
    if len(seeds) != num_envs:
        raise ValueError(
            f"seed as a list must have one entry per env (num_envs={num_envs}), got {len(seeds)}"
        )
    return seeds


def batch_actions(
    actions: Any,
    shape: tuple[int, int, int],
    stepping: Any,
    every: bool,
    xp: Any,
    on_device: Any,
    device: Any = None,
    dtype: Any = None,
) -> Any:
    """The actions of a step as a (B, R, d) array of the env's library, checked.

    `actions` is a numpy array (or nested sequence) or a torch tensor of shape (B, R d) or
    (B, R, d), `shape` = (B, R, d); of a real dtype (every row) and finite (the rows of the
    (B,) mask `stepping`, on the env's device; all of them where `every`). Rows that do not
    step are zeroed (an autoresetting env ignores its action, as SyncVectorEnv does, so a NaN
    there never reaches the batch). `xp` is the env's array namespace, `on_device` moves a host
    array to the env's device; `device` and `dtype` are the torch env's (a tensor goes there
    directly).
    """
    b, rows, d = shape
    if arrays.is_torch(actions):
        # torch dtypes are floating, integer, complex or bool: the last two are not real
        if actions.is_complex() or str(actions.dtype) == "torch.bool":
            raise TypeError(f"actions must hold real numbers, got a tensor of {actions.dtype}")
        if device is not None:
            arr = actions.to(device=device, dtype=dtype)
        else:
            arr = real_array("actions", arrays.to_numpy(actions.detach()), finite=False)
    else:
        # the dtype is checked for every row; finiteness below only for the rows that step
        arr = on_device(real_array("actions", actions, finite=False))
    if tuple(arr.shape) not in ((b, rows * d), (b, rows, d)):
        raise ValueError(
            f"actions must have shape ({b}, {rows * d}) or ({b}, {rows}, {d}), got "
            f"{tuple(arr.shape)}"
        )
    arr = xp.reshape(arr, (b, rows, d))
    if not bool(xp.all(xp.isfinite(arr if every else arr[stepping]))):
        raise ValueError("actions must be finite, got NaN or inf entries")
    if not every:
        arr = xp.where(stepping[:, None, None], arr, 0.0)
    return arr
