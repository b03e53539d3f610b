"""Accepted ranges of every numeric input, and the checks that enforce them.

Every parameter of the swarm model (`agent_envs.params.SwarmParams`), every env keyword
argument, reset option and action, and every argument of `agent_envs.simulator.simulate` goes
through the checks below. A bad value raises `TypeError` (not a real number: a string, a bool,
a complex number, ``None``) or `ValueError` (NaN, inf, an integer too large for a float, or a
value outside the range) whose message names the input and its accepted range.

## Why these ranges

The ranges are chosen so that for EVERY accepted value the rewards, the observations and the
spaces of the envs are finite (in float32 as well as float64), and the arrays have a size that
an index can address. Write R = `divergence_threshold`, M = `max_control`, T = `horizon`,
m = `n_steps`, tau = T / m, gamma, N = `n_agents`, d = `dim`, w = 1/eps (the kernel weights).

- Positions. A state with some |x_k,i| > R ends the episode and is never kept or observed, the
  uniform start lies in [-1, 1]^d (so R >= 1 keeps it inside), given initial positions must lie
  inside R, and |xbar_i| < R. So every kept or observed coordinate has |x_k,i| <= R and
  |x_k,i - xbar_i| <= 2 R.
- Rewards. The running cost (`eq:running_cost`) of a kept state and a clipped control is

      c = (1/N) sum_k (|x_k - xbar|^2 + gamma |u_k|^2) <= d (4 R^2 + gamma M^2),

  the step reward is -tau c with tau <= T, and the return of an episode is at most T times that
  bound (the steps' tau add up to T). With R <= 1e6, M <= 1e6, gamma <= 1e6, T <= 1e6 and
  N d <= 1e7 (so d <= 5e6): |return| <= 1e6 * 5e6 * (4e12 + 1e18) ~ 5e30, finite in float32
  (max ~3.4e38) and float64.
- Interaction drift (observed). For the Cucker-Smale kernel p = w / (alpha^2 + |r|^2)
  (`eq:symmker`, `eq:nonsymmker`), |r| / (alpha^2 + |r|^2) <= 1 / (2 alpha), so every
  coordinate of the drift (1/N) sum_l p(x_k, x_l)(x_l - x_k) is at most
  max(w) / (2 alpha) <= 1 / (2 eps_min alpha). With eps >= 1e-12 and alpha >= 1e-6 this is
  <= 5e17: the observation space's bound is finite in float32. The largest kernel value,
  w / alpha^2 <= 1e24, and the largest entry of the frozen linearization L(x) or of the exact
  Jacobian (<= 3 w / alpha^2 in absolute value) are finite too, and so are tau L <= 1e30 and
  the drift sums before the division by N (<= N * 1e24 * 2 R <= 2e37).
- alpha <= 1e6 keeps alpha^2 <= 1e12 (alpha = 1e200 overflowed alpha^2 to inf), and
  eps <= 1e12 keeps w = 1/eps >= 1e-12, a normal float (eps = 1e-320 made w = inf).
- Noise. |sigma dW| = sigma sqrt(tau) |z| <= 1e6 * 1e3 |z|: finite for every normal draw z.
  A step whose state leaves R (or is not finite) is flagged `diverged`, never kept.
- Sizes. N d <= 1e7 keeps the spaces (2 N d + d + 1 float32 entries) and the state constructible
  (dim = 2**40 was a MemoryError), and n_paths N d <= 1e8 bounds one float64 state batch to
  800 MB. The dense kernel matrix needs n_paths N^2 entries per step: that memory depends on
  the machine and is not capped here. n_steps <= 1e9 keeps tau >= T 1e-9 > 0.

The time fraction t/T lies in [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Range:
    """A closed (or, with `low_open`, half-open) interval of accepted values."""

    low: float
    high: float
    low_open: bool = False

    def __contains__(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        return above and value <= self.high

    def __str__(self) -> str:
        return f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}]"


#: |x| bound of positions, the target and the divergence threshold R.
MAX_POSITION = 1e6
#: Accepted ranges of the real-valued inputs (see the module docstring for the derivation).
ALPHA_RANGE = Range(1e-6, 1e6)
EPSILON_RANGE = Range(1e-12, 1e12)
SIGMA_RANGE = Range(0.0, 1e6)
HORIZON_RANGE = Range(1e-6, 1e6)
GAMMA_RANGE = Range(0.0, 1e6)
MAX_CONTROL_RANGE = Range(0.0, 1e6, low_open=True)
DIVERGENCE_THRESHOLD_RANGE = Range(1.0, MAX_POSITION)
TARGET_RANGE = Range(-MAX_POSITION, MAX_POSITION)
#: Accepted ranges of the integer inputs.
MAX_AGENTS = 10**7
MAX_STATE_SIZE = 10**7  # N d
MAX_BATCH_SIZE = 10**8  # n_paths N d
MAX_STEPS = 10**9
MAX_PATHS = 10**6
#: Largest seed a command line accepts (every seed option: 0 <= seed <= MAX_SEED). SB3 seeds
#: numpy's legacy global generator, which takes 32-bit seeds; the envs themselves accept any
#: int >= 0 (`check_seed`).
MAX_SEED = 2**32 - 1

_REAL_TYPES = (int, float, np.integer, np.floating)
_NUMERIC_KINDS = "iuf"  # signed int, unsigned int, float: numpy's real numeric dtypes


def _shown(value: Any) -> str:
    """`value` for an error message; a huge int by its size (str() of it may itself fail)."""
    if isinstance(value, (int, np.integer)) and abs(int(value)) >= 10**15:
        return f"an integer of {int(value).bit_length()} bits"
    return f"{value:g}" if isinstance(value, (float, np.floating)) else repr(value)


def _is_real_scalar(value: Any) -> bool:
    return isinstance(value, _REAL_TYPES) and not isinstance(value, (bool, np.bool_))


def check_real(name: str, value: Any, accepted: Range | None = None) -> float:
    """`value` as a finite float in `accepted` (any finite value if None).

    Raises `TypeError` naming `name` for anything but an int or a float (numpy's included; bool,
    str, complex and None are rejected), `ValueError` naming `name` and the range for NaN, inf,
    an int too large for a float, or a value outside `accepted`.
    """
    where = f" in {accepted}" if accepted is not None else ""
    if not _is_real_scalar(value):
        kind = type(value).__name__
        raise TypeError(f"{name} must be a real number (int or float){where}, got {kind}")
    try:
        result = float(value)
    except OverflowError:
        shown = _shown(value)
        raise ValueError(f"{name} must be a finite real number{where}, got {shown}") from None
    if not math.isfinite(result):
        raise ValueError(f"{name} must be a finite real number{where}, got {result}")
    if accepted is not None and result not in accepted:
        raise ValueError(f"{name} must be a real number in {accepted}, got {result:g}")
    return result


def check_positive(name: str, value: Any, accepted: Range | None = None) -> float:
    """`value` as a finite float in `accepted` (default (0, inf)); errors as `check_real`."""
    if accepted is None:
        accepted = Range(0.0, math.inf, low_open=True)
    return check_real(name, value, accepted)


def check_int(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    """`value` as an int in [minimum, maximum] (bools rejected); TypeError/ValueError naming it."""
    high = "" if maximum is None else f", {maximum}"
    allowed = f"[{minimum}{high}]" if maximum is not None else f">= {minimum}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer {allowed}, got {type(value).__name__}")
    if value < minimum or (maximum is not None and value > maximum):
        raise ValueError(f"{name} must be an integer {allowed}, got {_shown(value)}")
    return int(value)


def check_seed(seed: Any) -> int | None:
    """`seed` as None or an int >= 0 (numpy ints accepted, bools rejected).

    Gymnasium's own check raises `gymnasium.error.Error` and accepts ``True``; the envs call
    this first so that a bad seed is a `TypeError`/`ValueError` naming ``seed``. Any size of int
    is fine (numpy's `SeedSequence` takes arbitrary precision).
    """
    if seed is None:
        return None
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise TypeError(f"seed must be None or an integer >= 0, got {type(seed).__name__}")
    if seed < 0:
        raise ValueError(f"seed must be None or an integer >= 0, got {_shown(seed)}")
    return int(seed)


def real_array(name: str, value: Any, *, finite: bool = True) -> np.ndarray:
    """`value` as a finite float64 array; errors name `name`.

    With ``finite=False`` only the dtype is checked (the caller checks finiteness where it
    matters, e.g. on the rows of a vector env that step).

    Accepted: anything numpy turns into an array of a real numeric dtype (signed or unsigned
    integers, floats of any width), e.g. lists of Python numbers, numpy arrays, torch CPU
    tensors. An ``object`` array (e.g. a list holding an int too large for int64) is accepted
    when every entry is a real number in the sense of `check_real` (no bools, strings or
    complex numbers); its entries are converted one by one. Rejected with `TypeError`: strings,
    bools, complex numbers, None and ragged nestings; with `ValueError`: NaN, inf and ints too
    large for a float64.
    """
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged nesting, unconvertible object
        raise TypeError(f"{name} must be an array of real numbers: {exc}") from None
    kind = arr.dtype.kind
    if kind == "O":
        flat = arr.reshape(-1)
        out = np.empty(flat.shape, dtype=np.float64)
        for i, entry in enumerate(flat):
            if not _is_real_scalar(entry):
                raise TypeError(
                    f"{name} must hold real numbers (int or float), got an entry of type "
                    f"{type(entry).__name__}"
                )
            try:
                out[i] = float(entry)
            except OverflowError:
                raise ValueError(f"{name} must be finite, got {_shown(entry)}") from None
        result = out.reshape(arr.shape)
    elif kind in _NUMERIC_KINDS:
        with np.errstate(over="ignore"):  # a float128 beyond float64 becomes inf, caught below
            result = arr.astype(np.float64)
    else:
        raise TypeError(f"{name} must hold real numbers (int or float dtype), got {arr.dtype}")
    if finite and not np.all(np.isfinite(result)):
        raise ValueError(f"{name} must be finite, got NaN or inf entries")
    return result


def check_size(name: str, value: int, size: int, maximum: int, what: str) -> None:
    """Raise `ValueError` naming `name` when the product `size` exceeds `maximum`."""
    if size > maximum:
        raise ValueError(f"{name}={value} makes {what} = {size} entries, more than {maximum:.0e}")
