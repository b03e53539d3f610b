"""The one loader and switch of the compiled (numba) paths, and their thread dispatch.

Each compiled path has a name (`PATHS`): the numba module that holds it, what it serves, and
the numpy module that owns it (calls it where it applies and keeps the reference it replaces):

==========  =====================  ===================================  ===========================
name        module                 serves                               owner (numpy reference)
==========  =====================  ===================================  ===========================
"kernel"    `native.kernel`        P's lower triangle, s = P 1 and      `dynamics.laplacian`
                                   L(x) x for the symmetric kernel      (`fill_cucker_smale`)
"lanczos"   `native.lanczos`       the Lanczos phi-action of the        `integrators.phi_fused`
                                   frozen L(x)                          (`phi_lanczos`)
"fused"     `native.lanczos`       an ERB/SERB step and the next        `integrators.exponential`
            (`frozen_advance`)     kernel pass in one call; needs       (the general step)
                                   "kernel" and "lanczos"
"noise"     `native.noise`         numpy's normals from many            `draws` (checked:
                                   generators in one call               `_draws_equal_numpys`)
"step"      `native.step`          the native vector env's prologue     `envs.fast_step` (checked:
                                   and epilogue                         `same_as_numpy`)
==========  =====================  ===================================  ===========================

`available(name)` answers whether a path serves, and loads it on its first call: it imports
the module (numba), and runs its check (`import_checked`): for "noise" and "step" the owner's
reference check, registered by the owner when it is imported (`register_check`), which
compares the compiled values with numpy's bit for bit; for "kernel" and "lanczos" one call
with the argument types of the owner's calls (numba keeps one machine code per argument type,
read-only included, so this loads the machine code the steps run). A check that answers False
or raises leaves the path off with a RuntimeWarning that says what runs instead. The owners
call `available` where their objects are made (a model, an integrator, an env), so the load
falls there and not in a step.

One switch: ``AGENT_ENVS_NUMBA=0`` in the environment turns every path off (read when a path
loads); `use(name, on)` turns one on or off for this process (for comparisons in one process:
tests, benchmarks); `status()` lists which paths serve. Without numba every path is off and
the package works on its numpy paths. `numba` is imported in this package only: here (the
threads) and in the leaf modules, which import nothing above them.
"""

from __future__ import annotations

import importlib
import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from agent_envs.native.lanczos_rule import MAX_CHECK_STEP

#: set to "0" to keep every numpy path even where numba is installed
ENV_VAR = "AGENT_ENVS_NUMBA"


@dataclass(frozen=True)
class CompiledPath:
    """One compiled path: its numba module (dotted name), what it serves, the numpy module
    that owns it, and the paths it needs on besides its own switch."""

    module: str
    serves: str
    owner: str
    requires: tuple[str, ...] = ()


#: the compiled paths by name (module docstring)
PATHS: dict[str, CompiledPath] = {
    "kernel": CompiledPath(
        "agent_envs.native.kernel",
        "the symmetric Cucker-Smale kernel pass: P's lower triangle, s = P 1, L(x) x",
        "agent_envs.dynamics.laplacian",
    ),
    "lanczos": CompiledPath(
        "agent_envs.native.lanczos",
        "the Lanczos phi-action of the frozen L(x)",
        "agent_envs.integrators.phi_fused",
    ),
    "fused": CompiledPath(
        "agent_envs.native.lanczos",
        "the fused ERB/SERB step: phi-action, update and next kernel pass in one call",
        "agent_envs.integrators.exponential",
        requires=("kernel", "lanczos"),
    ),
    "noise": CompiledPath(
        "agent_envs.native.noise",
        "the native vector env's Brownian draws from every env's generator in one call",
        "agent_envs.simulator",
    ),
    "step": CompiledPath(
        "agent_envs.native.step",
        "the native vector env's prologue and epilogue around its fused pass",
        "agent_envs.envs.fast_step",
    ),
}
#: per path: its module once loaded and checked (for "fused", True); False: off (numba missing,
#: ``AGENT_ENVS_NUMBA=0``, `use(name, False)`, or a check that failed); None: not tried yet
_loaded: dict[str, Any] = dict.fromkeys(PATHS)
#: the owners' reference checks: name -> (check, what runs instead)
_checks: dict[str, tuple[Callable[[Any], bool], str]] = {}
#: (name, threads) whose threaded driver `load_compiled_threads` has loaded
_threads_loaded: set[tuple[str, int]] = set()
_REQUIRES = {name: path.requires for name, path in PATHS.items() if path.requires}


def _path(name: str) -> CompiledPath:
    found = PATHS.get(name) if isinstance(name, str) else None
    if found is None:
        raise ValueError(f"unknown compiled path {name!r}; the known ones: {', '.join(PATHS)}")
    return found


def import_compiled(module: str) -> Any:
    """The numba-compiled module `module` (e.g. ``"agent_envs.native.kernel"``), or False:
    numba not importable, or ``AGENT_ENVS_NUMBA=0`` in the environment."""
    if os.environ.get(ENV_VAR, "1") == "0":
        return False
    try:
        return importlib.import_module(module)
    except ImportError:
        return False


def import_checked(module: str, check: Callable[[Any], bool], fallback: str) -> Any:
    """`import_compiled(module)`, kept only where `check(module)` answers True (a compiled
    module checked against the numpy calls it replaces): False where numba is missing or
    switched off, and, with a RuntimeWarning that names `fallback` (what runs instead), where
    the check answers False (another numpy, say) or raises (a numba that cannot build it)."""
    found = import_compiled(module)
    if found is False:
        return False
    try:
        same = check(found)
    except Exception as exc:  # a numba or llvmlite that cannot build it
        warnings.warn(
            f"{module} did not load ({type(exc).__name__}: {exc}); {fallback}",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    if not same:
        warnings.warn(
            f"{module} differs from numpy on this install; {fallback}",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    return found


def register_check(name: str, check: Callable[[Any], bool], fallback: str) -> None:
    """Make `check(module)` the reference check of path `name`, run when it loads (it answers
    whether the compiled module gives the owner's numpy values); `fallback` says what runs
    where it fails. The owners ("noise", "step") call this when they are imported."""
    _path(name)
    _checks[name] = (check, fallback)


def available(name: str) -> bool:
    """Whether compiled path `name` (`PATHS`) serves: its switch on (`use`, ``AGENT_ENVS_NUMBA``),
    numba importable, its module loaded and checked (on the first call), and, for "fused", the
    kernel pass and the Lanczos available too. ValueError for an unknown name."""
    found = _loaded.get(name)
    if found is None:
        found = _load(name)
    if found is False:
        return False
    requires = _REQUIRES.get(name)
    return requires is None or all(available(other) for other in requires)


def loaded(name: str) -> Any:
    """The module of compiled path `name` (`available(name)` must have answered True)."""
    return _loaded[name]


def use(name: str, on: bool) -> bool:
    """Switch compiled path `name` on (loading it: numba installed, ``AGENT_ENVS_NUMBA`` not 0,
    its check passed) or off for this process; returns whether its own switch was on before
    (for "fused": not counting the paths it needs). ValueError for an unknown name."""
    _path(name)
    found = _loaded[name]
    before = (_load(name) if found is None else found) is not False
    _loaded[name] = None if on else False
    if on:
        _load(name)
    return before


def status() -> dict[str, bool]:
    """Which compiled paths serve in this process: name -> `available(name)` (loading each
    path not tried yet)."""
    return {name: available(name) for name in PATHS}


def _load(name: str) -> Any:
    path = _path(name)
    if name in _REQUIRES:  # a switch over the code of the paths it needs: loads nothing
        found: Any = os.environ.get(ENV_VAR, "1") != "0"
    else:
        if name in _WARM_UPS:
            check, fallback = _WARM_UPS[name]
        elif name in _checks:
            check, fallback = _checks[name]
        else:
            raise RuntimeError(
                f"compiled path {name!r} has no reference check: {path.owner} registers it "
                "when it is imported (import agent_envs)"
            )
        found = import_checked(path.module, check, fallback)
    _loaded[name] = found
    return found


def _read_only(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


#: the argument types of the owners' calls that the warm-ups need besides arrays: the
#: Lanczos's `max_step` (an int, as `native.lanczos_rule.MAX_CHECK_STEP`; its value is
#: irrelevant here) and the empty bounds and extra vectors (read-only, as
#: `integrators.phi_fused` passes them)
_MAX_STEP = MAX_CHECK_STEP
_NO_BOUNDS = _read_only(np.empty(0))
_NO_EXTRA = _read_only(np.empty((0, 0, 0)))


def _warm_up_kernel(module: Any) -> bool:
    """One call of the kernel pass and of `mirror_lower` with the argument types of
    `laplacian`'s calls (a read-only x), so that loading the machine code happens here."""
    x = _read_only(np.zeros((1, 2, 1)))
    module.cucker_smale_drift(
        x, 1.0, 1.0, np.empty((1, 2, 2)), np.empty((1, 2)), np.empty((1, 2, 1))
    )
    module.mirror_lower(np.zeros((1, 2, 2)))
    return True


def _warm_up_lanczos(module: Any) -> bool:
    """One compiled call with the argument types of `integrators.phi_fused`'s calls (a
    read-only P, as the model's workspace hands out), so that loading the machine code
    happens here. False, with a warning, where the cached machine code was compiled against
    another version of the files it links in (`native.lanczos.RULE_STAMP`)."""
    if module.compiled_rule_stamp() != module.RULE_STAMP:
        warnings.warn(
            "the compiled Lanczos in numba's cache was built from other versions of "
            "agent_envs/native/lanczos_rule.py, lanczos_tridiagonal.py or kernel.py than these "
            "(numba does not see edits to other files); the numpy Lanczos runs. Delete the "
            "cache (agent_envs/native/__pycache__/lanczos.*.nbi, *.nbc, or NUMBA_CACHE_DIR) "
            "to compile it again",
            RuntimeWarning,
            stacklevel=4,
        )
        return False
    p = np.full((1, 3, 3), 0.5)
    np.fill_diagonal(p[0], 1.0)
    p = _read_only(p)
    s = _read_only(p.sum(axis=-1))
    v = _read_only(np.ones((1, 3, 1)))
    for extra in (_NO_EXTRA, v):
        module.frozen_lanczos(
            p, s, 0.1, v, 1, 1e-10, 3, _MAX_STEP, _NO_BOUNDS, _NO_BOUNDS, _NO_BOUNDS, 1.0,
            np.empty((1, 3, 1)), np.empty(1, dtype=bool), extra, 1.0,
        )  # fmt: skip
        # `frozen_advance`'s types: P the workspace's writable buffer, the outputs fresh
        module.frozen_advance(
            np.array(p), s, 0.1, v, 1e-10, 3, _MAX_STEP, 1.0, np.empty((1, 3, 1)), extra,
            1.0, v, 0.1, v, 1.0, 1.0, np.empty((1, 3, 1)), np.empty((1, 3)), np.empty((1, 3, 1)),
        )  # fmt: skip
    return True


#: the paths without an owner's check: their warm-up, and what runs where it fails
_WARM_UPS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "kernel": (_warm_up_kernel, "the numpy kernel passes run"),
    "lanczos": (_warm_up_lanczos, "the numpy Lanczos runs"),
}


# ---------------------------------------------------------------------------- threads
def max_compiled_threads() -> int:
    """The most threads the compiled passes may use in this process: numba's
    ``NUMBA_NUM_THREADS`` (its default: the CPUs it sees), or 1 where the compiled kernel pass
    is not available (no numba, ``AGENT_ENVS_NUMBA=0``, or switched off)."""
    if not available("kernel"):
        return 1
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


def check_compiled_threads(value: Any, name: str = "num_threads") -> int:
    """`value` as the number of threads of the compiled passes: an int in [1,
    `max_compiled_threads`]; else TypeError or ValueError naming `name` and the range (above 1
    without numba: the message says what to install)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an int >= 1, got {value!r}")
    most = max_compiled_threads()
    if value < 1 or value > most:
        if value > 1 and most == 1:
            raise ValueError(
                f"{name}={value}: threads need the compiled passes (numba: pip install "
                f"'agent-envs[fast]', and {ENV_VAR} not 0); without them {name} must be 1"
            )
        raise ValueError(f"{name} must be an int in [1, {most}] (numba's threads), got {value}")
    return int(value)


@contextmanager
def compiled_threads(threads: int) -> Iterator[None]:
    """numba's parallel regions on `threads` threads inside (`numba.set_num_threads`, which
    holds for the calling thread; its value before is restored on exit). The first use starts
    numba's threading layer (TBB where installed, else OpenMP, else its own workqueue; with GNU
    OpenMP a process forked after that is terminated by numba when it runs threads: the
    `SwarmVectorEnv` docstring, "Threads")."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def call_on_threads(
    one: Callable[..., Any],
    spans: Callable[..., Any],
    args: tuple[Any, ...],
    members: int,
    threads: int,
) -> Any:
    """A compiled pass over `members` batch members: ``one(*args)`` on the calling thread, or,
    for `threads` > 1 and more than one member, its threaded driver ``spans(*args, k)`` on
    k = min(threads, members) contiguous spans of members on numba's threads (inside
    `compiled_threads`); the driver's result either way."""
    if threads > 1 and members > 1:
        with compiled_threads(threads):
            return spans(*args, min(threads, members))
    return one(*args)


def load_compiled_threads(threads: int) -> bool:
    """Whether the compiled kernel pass can run on `threads` threads (1 <= threads <=
    `max_compiled_threads`); loads its threaded driver and, where the Lanczos is available,
    the fused step's (`frozen_advance_threads`) with one call each (numba's threading layer
    starts there), so that this cost falls where this is called (the envs' first reset) and
    not in a step. (Not in a constructor: a process that forks after GNU OpenMP started loses
    its children to it.)"""
    if threads < 1 or threads > max_compiled_threads():
        return False
    if threads > 1:
        for name, warm_up in _THREAD_WARM_UPS.items():
            if (name, threads) not in _threads_loaded and available(name):
                _threads_loaded.add((name, threads))
                warm_up(_loaded[name], threads)
    return True


def _warm_up_kernel_threads(module: Any, threads: int) -> None:
    x = _read_only(np.zeros((2, 2, 1)))
    call_on_threads(
        module.cucker_smale_drift,
        module.cucker_smale_drift_threads,
        (x, 1.0, 1.0, np.empty((2, 2, 2)), np.empty((2, 2)), np.empty((2, 2, 1))),
        2,
        threads,
    )


def _warm_up_lanczos_threads(module: Any, threads: int) -> None:
    p = _read_only(np.full((2, 3, 3), 0.5))
    s = _read_only(p.sum(axis=-1))
    v = _read_only(np.ones((2, 3, 1)))
    for extra in (_NO_EXTRA, v):
        args = (np.array(p), s, 0.1, v, 1e-10, 3, _MAX_STEP, 1.0, np.empty((2, 3, 1)), extra,
                1.0, v, 0.1, v, 1.0, 1.0, np.empty((2, 3, 1)), np.empty((2, 3)),
                np.empty((2, 3, 1)))  # fmt: skip
        call_on_threads(module.frozen_advance, module.frozen_advance_threads, args, 2, threads)


#: the paths with a threaded driver, in the order they load
_THREAD_WARM_UPS: dict[str, Callable[[Any, int], None]] = {
    "kernel": _warm_up_kernel_threads,
    "lanczos": _warm_up_lanczos_threads,
}
