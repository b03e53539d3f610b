"""Exponential Rosenbrock-Euler schemes, deterministic (ERB) and stochastic (SERB).

With A = J_n either the exact Jacobian of the drift at x^n (`eq:jac`) or the frozen-kernel
linearization L(x^n) (see `agent_envs.dynamics.swarm`), and additive noise sigma dW:

- ERB (`eq:expRB`):  x+ = x + dt phi1(dt A) F(x, u) + sigma dW
  (for sigma = 0 exactly `eq:expRB`; with noise the increment is simply added).
- SERB (`eq:serb`, `eq:exp_int_discr`):
      x+ = x + dt phi1(dt A) (F(x, u) + sigma A dW) + sigma dW + dt^2 phi2(dt A) v,
  where v = du/dt (t_n) is the control's time derivative when supplied (`eq:serbaut`),
  and 0 otherwise. For sigma = 0 and v = 0 SERB is ERB.

With the exact Jacobian, ERB has deterministic order 2; with the frozen L(x) it is exponential
Euler for x' = L(x) x + u, of order 1. SERB has strong order 1 for additive noise either way.
"""

from __future__ import annotations

from typing import Any

from agent_envs import arrays, native
from agent_envs.dynamics.laplacian import FrozenLaplacian
from agent_envs.integrators.base import DriftModel, Integrator, LinearizationCachingModel
from agent_envs.integrators.phi_functions import (
    PHI_METHODS,
    frozen_advance,
    frozen_advance_applies,
    phi_action,
)

JACOBIAN_CHOICES = ("exact", "frozen")


class RosenbrockEuler(Integrator):
    """Common code of ERB and SERB; `stochastic_correction` adds the sigma A dW term."""

    needs_jacobian = True
    stochastic_correction = False
    #: whether `step` takes the fused step (`fused_step`): None (default) where it applies;
    #: False never; True where it applies, and a model with a ``fallbacks`` counter (the envs')
    #: counts a step where it did not ("fused-declined"). The envs set it from their step plan
    #: (`agent_envs.envs.step_plan.StepPlan.fused`), so that their steps take the path the plan
    #: shows even where a compiled path was switched after the env was made.
    fused: bool | None = None

    def __init__(self, jacobian: str = "frozen", phi_method: str = "auto") -> None:
        if jacobian not in JACOBIAN_CHOICES:
            raise ValueError(f"jacobian must be one of {JACOBIAN_CHOICES}, got {jacobian!r}")
        if phi_method not in PHI_METHODS:
            raise ValueError(f"phi_method must be one of {PHI_METHODS}, got {phi_method!r}")
        self.jacobian = jacobian
        self.phi_method = phi_method
        if phi_method in ("auto", "krylov"):
            native.available("lanczos")  # its one-time load falls here, not in a step

    @property
    def deterministic_order(self) -> float:  # type: ignore[override]
        return 2.0 if self.jacobian == "exact" else 1.0

    def step(self, model: DriftModel, x, u, t, dt, dW, du_dt=None) -> Any:
        rhs, lin = model.drift_and_linearization(t, x, u, self.jacobian)
        noise = model.sigma * dW
        if self.fused is not False and du_dt is None and dt != 0.0:
            found = self.fused_step(model, lin.matrix, rhs, x, dt, noise)
            if found is GAVE_UP:  # the workspace's P was partly overwritten: L(x) again
                return self.general_step(model, x, u, t, dt, noise, du_dt)
            if found is not None:
                return found
            if self.fused and getattr(model, "fallbacks", None) is not None:
                model.fallbacks["fused-declined"] += 1
        return self._phi_step(model, rhs, lin, x, dt, noise, du_dt)

    def general_step(self, model: DriftModel, x, u, t, dt, noise, du_dt=None) -> Any:
        """`step` without the fused step, from noise = sigma dW: L(x) and F(x, u) evaluated
        again and the phi-action (what `step` takes after a fused step gave up; the single
        envs' compiled step takes it there too)."""
        rhs, lin = model.drift_and_linearization(t, x, u, self.jacobian)
        return self._phi_step(model, rhs, lin, x, dt, noise, du_dt)

    def _phi_step(self, model: DriftModel, rhs, lin, x, dt, noise, du_dt) -> Any:
        """x + dt phi_1(dt A) (F + sigma A dW) + noise (+ dt^2 phi_2(dt A) du/dt) from
        rhs = F(x, u) (..., N, d) and its linearization `lin` (module docstring)."""
        scaled = dt * lin.matrix
        kw = {"method": self.phi_method, "symmetric": lin.symmetric}
        if lin.bounds is not None:
            kw["bounds"] = lin.scaled_bounds(dt)
        correction = None
        if self.stochastic_correction and model.sigma != 0.0:
            if isinstance(lin.matrix, FrozenLaplacian) and dt != 0.0:
                # F + sigma A dW with the product A dW = (tau A) dW / tau taken in the
                # phi-action's pass over A (the compiled frozen L(x))
                correction = (lin.as_columns(noise), 1.0 / dt)
            else:
                rhs = rhs + lin.apply(noise)
        incr = dt * phi_action(scaled, lin.as_columns(rhs), 1, add_product=correction, **kw)
        if du_dt is not None:
            v = arrays.namespace(rhs).broadcast_to(du_dt, tuple(rhs.shape))
            incr = incr + dt**2 * phi_action(scaled, lin.as_columns(v), 2, **kw)
        return x + lin.from_columns(incr, x) + noise

    def fused_step(
        self,
        model: LinearizationCachingModel,
        operator: Any,
        rhs: Any,
        x: Any,
        dt: float,
        noise: Any,
    ) -> Any:
        """The step and the model's next kernel pass in one compiled pass, member by member
        (`phi_functions.frozen_advance`), for a model that keeps its linearization
        (`LinearizationCachingModel`: the envs' `LinearizationCache`) on the compiled frozen
        L(x) (`operator`, the `FrozenLaplacian` of `model.drift_and_linearization`), with
        rhs = F(x, u) and noise = sigma dW: x_next, equal bit for bit to the general path's;
        None where it does not apply (a model without the protocol's hooks among them);
        `GAVE_UP` when a member's Lanczos did not converge (the model's workspace is then
        discarded and L(x) must be computed again). The native vector env calls it directly
        (`agent_envs.envs.vector_env`), with rhs from its compiled prologue.

        The compiled path "fused" (``native.use("fused", False)`` switches it off) is asked
        last: where the step applies, the kernel pass and the Lanczos it needs are loaded
        already (by the model and this integrator when they were made), so asking loads
        nothing in a step."""
        relinearize = getattr(model, "fused_relinearization", None)
        if (
            relinearize is None
            or not frozen_advance_applies(operator, rhs, x, noise, self.phi_method)
            or not native.available("fused")
        ):
            return None
        target = relinearize(x)
        if target is None:
            return None
        correction = 1.0 / dt if self.stochastic_correction and model.sigma != 0.0 else None
        threads = getattr(model, "threads", 1)
        found = frozen_advance(operator, rhs, x, dt, noise, correction, *target, threads)
        if found is None:
            model.discard_linearization()
            return GAVE_UP
        model.adopt_linearization(*found)
        return found[0]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(jacobian={self.jacobian!r}, phi_method={self.phi_method!r})"


#: returned by `RosenbrockEuler.fused_step` when it wrote part of the model's P and gave up
GAVE_UP: Any = object()


def fused_step_enabled() -> bool:
    """Whether the exponential integrators take the fused step where it applies:
    ``native.available("fused")`` (its switch on, and the compiled kernel pass and Lanczos)."""
    return native.available("fused")


def use_fused_step(enabled: bool) -> bool:
    """``native.use("fused", enabled)``: switch the fused step (the phi-action and the model's
    next kernel pass in one compiled pass, `phi_functions.frozen_advance`) on or off for this
    process; returns whether its switch was on. Both give the same states bit for bit; for
    comparisons (tests, benchmarks)."""
    return native.use("fused", enabled)


class ExponentialRosenbrockEuler(RosenbrockEuler):
    """ERB, `eq:expRB`."""

    name = "erb"
    strong_order = 1.0  # additive noise: the uncorrected sigma dW term is still order 1
    stochastic_correction = False


class StochasticExponentialRosenbrockEuler(RosenbrockEuler):
    """SERB, `eq:serb` / `eq:exp_int_discr` (+ the phi2 term of `eq:serbaut`)."""

    name = "serb"
    strong_order = 1.0
    stochastic_correction = True
