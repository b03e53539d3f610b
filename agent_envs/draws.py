"""Every random draw of a swarm simulation: start positions and Brownian increments.

All of them come from a `numpy.random.Generator` passed in (an env's ``self.np_random``, the
child generators `agent_envs.simulator.simulate` spawns from its seed); nothing here draws
from global state, and integrators never draw.

- `uniform_positions`: x^0 ~ U([-1, 1]^d) per agent, shape (N, d) (the paper's start);
- `brownian_increments`: dW ~ N(0, dt I) of any shape, sqrt(dt) z with z from `rng`;
- `fill_brownian_increments`: the same bits for a batch whose rows each draw from their own
  generator (the native vector env), in one compiled call where `agent_envs.native.noise` is
  available (`GeneratorHandles`: the generators' C handles), else one numpy call per row.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from typing import Any

import numpy as np

from agent_envs import native


def uniform_positions(rng: np.random.Generator, n_agents: int, dim: int) -> np.ndarray:
    """N agents drawn uniform on [-1, 1]^d (the paper's start); shape (N, d)."""
    return rng.uniform(-1.0, 1.0, size=(n_agents, dim))


def brownian_increments(rng: np.random.Generator, shape: tuple[int, ...], dt: float):
    """Increments dW ~ N(0, dt I) of the given shape: sqrt(dt) z for z = standard normals from
    `rng`, scaled in place (one array, no temporary).

    `fill_brownian_increments` gives the same bits for a batch whose rows each draw from their
    own generator."""
    increments = rng.standard_normal(shape)
    increments *= np.sqrt(dt)
    return increments


def load_compiled_noise() -> bool:
    """``native.available("noise")``: whether `fill_brownian_increments` draws a batch in one
    compiled call (`agent_envs.native.noise`, needs numba); loads it on the first call (the
    native vector env asks when it is made, not in a step) and checks there, by
    `_draws_equal_numpys` (registered with the loader below), that its normals and the
    generators' states after them are numpy's bit for bit. False where numba is missing or
    switched off (``AGENT_ENVS_NUMBA=0``), and, with a warning, where the check fails or the
    module does not compile: the compiled draws are then never used."""
    return native.available("noise")


def _draws_equal_numpys(module: Any) -> bool:
    """Whether `module.fill_standard_normal` gives numpy's normals and leaves the generators'
    states as numpy's calls leave them (two fixed-seed generators, 4096 draws each: about 50
    through the ziggurat's wedges)."""
    rngs = [np.random.default_rng(seed) for seed in (0, 1)]
    twins = [np.random.default_rng(seed) for seed in (0, 1)]
    out = np.zeros((3, 4096))
    handles = GeneratorHandles(rngs)
    module.fill_standard_normal(
        handles.states, handles.next_uint64, handles.next_double,
        np.array([1, 0]), np.array([2, 0]), out, 1.0,
    )  # fmt: skip
    expected = np.stack(
        [twins[0].standard_normal(4096), np.zeros(4096), twins[1].standard_normal(4096)]
    )
    same_states = all(
        a.bit_generator.state == b.bit_generator.state for a, b in zip(rngs, twins, strict=True)
    )
    return bool(np.array_equal(out, expected) and same_states)


native.register_check(
    "noise",
    lambda module: _draws_equal_numpys(module),  # (looked up when called: tests swap it)
    "the native vector env draws with one numpy call per env",
)


def use_compiled_noise(enabled: bool) -> bool:
    """``native.use("noise", enabled)``: switch the compiled draws on (when numba is installed
    and they equal numpy's) or off for this process; returns whether they were in use
    before."""
    return native.use("noise", enabled)


def _function_address(function: Any) -> int:
    return int(ctypes.cast(function, ctypes.c_void_p).value or 0)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class GeneratorHandles:
    """The C handles of numpy generators, for `fill_brownian_increments`'s compiled draws: per
    generator, the address of its bit generator's state and of its ``next_uint64`` and
    ``next_double`` functions (numpy's `BitGenerator.ctypes`), as read-only (G,) uintp arrays.

    It keeps the generators themselves (`rngs`, a tuple fixed at construction), so the
    addresses stay valid as long as it lives; `fill_brownian_increments` uses it only for the
    same generators in the same order (a generator replaced, e.g. by a seeded reset, needs new
    handles; the native vector env builds them again then). A copy (pickle, deepcopy) takes
    this process's addresses anew. numpy holds a bit generator's lock while it draws; the
    compiled draws do not, so the generators must not be used from another thread during
    `fill_brownian_increments`. Building handles costs about 2 us per generator."""

    __slots__ = ("next_double", "next_uint64", "rngs", "sources", "states")

    def __init__(self, rngs: Sequence[np.random.Generator]) -> None:
        rngs = tuple(rngs)
        for rng in rngs:
            if not isinstance(rng, np.random.Generator):
                raise TypeError(
                    f"rngs must be numpy.random.Generator objects, got {type(rng).__name__}"
                )
        handles = [rng.bit_generator.ctypes for rng in rngs]
        self.rngs: tuple[np.random.Generator, ...] = rngs
        self.states = _read_only(np.array([h.state_address for h in handles], dtype=np.uintp))
        self.next_uint64 = _read_only(
            np.array([_function_address(h.next_uint64) for h in handles], dtype=np.uintp)
        )
        self.next_double = _read_only(
            np.array([_function_address(h.next_double) for h in handles], dtype=np.uintp)
        )
        self.sources = _read_only(np.arange(len(rngs)))

    def __setattr__(self, name: str, value: Any) -> None:
        if hasattr(self, name):  # (each attribute is set once, in __init__)
            raise AttributeError(f"GeneratorHandles.{name} cannot be changed; build new handles")
        object.__setattr__(self, name, value)

    def __reduce__(self) -> tuple[Any, ...]:
        # the addresses belong to this process: a copy (pickle, deepcopy) takes new ones
        return (GeneratorHandles, (self.rngs,))

    def holds(self, rngs: Sequence[np.random.Generator]) -> bool:
        """Whether these handles are for exactly `rngs` (the same objects, in order)."""
        return self.rngs == tuple(rngs)


def fill_brownian_increments(
    rngs: Sequence[np.random.Generator],
    rows: Sequence[int],
    out: np.ndarray,
    dt: float,
    handles: GeneratorHandles | None = None,
) -> np.ndarray:
    """`brownian_increments` of out[i].shape from rngs[k] into out[i], for i = rows[k], the
    other rows of `out` (float64, C-contiguous; zeroed by the caller where some row is not
    drawn) left as they are; returns `out`.

    Each row's standard normals are drawn in place and scaled by sqrt(dt): the same draws from
    each generator and the same product, so the same bits as
    `brownian_increments(rngs[k], out[i].shape, dt)` (the native vector env's rows equal their
    single twins', tests/test_vector_env.py), without one temporary and one product per row.
    With `handles` (`GeneratorHandles` of `rngs`, else ValueError) and numba, the whole batch
    is one compiled call (`agent_envs.native.noise`: numpy's algorithm on the same bit
    generators, the same bits; 0.5 against 2.1 us per generator for 100 normals; the
    generators must not be used from another thread meanwhile), else one numpy call per row.
    A row outside `out` raises IndexError either way."""
    if handles is not None:
        if not handles.holds(rngs):
            raise ValueError("handles must be the GeneratorHandles of these rngs, in order")
        if len(rows) != len(handles.rngs):
            raise ValueError(f"rows must have one entry per generator, got {len(rows)}")
        if out.dtype == np.float64 and out.flags.c_contiguous and native.available("noise"):
            index = np.asarray(rows, dtype=np.int64).reshape(-1)
            size = out.shape[0]
            if index.size and not (index.min() >= -size and index.max() < size):
                raise IndexError(f"rows must index the {size} rows of out, got {rows!r}")
            native.loaded("noise").fill_standard_normal(
                handles.states, handles.next_uint64, handles.next_double, handles.sources,
                index % size if size else index, out.reshape(size, -1), float(np.sqrt(dt)),
            )  # fmt: skip
            return out
    for rng, row in zip(rngs, rows, strict=True):
        rng.standard_normal(out=out[row])
    out *= np.sqrt(dt)
    return out


__all__ = [
    "GeneratorHandles",
    "brownian_increments",
    "fill_brownian_increments",
    "load_compiled_noise",
    "uniform_positions",
    "use_compiled_noise",
]
