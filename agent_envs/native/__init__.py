"""Every numba kernel of the package, with its one loader and switch (numba is optional).

The leaf modules hold the compiled code and import nothing above this package (they may
import each other: the Lanczos uses the kernel pass's products):

- `kernel`: the symmetric Cucker-Smale kernel pass (P's lower triangle, s = P 1, L(x) x) and
  the half-read products over P's lower triangle;
- `lanczos`: the Lanczos phi-action of the frozen L(x) and the fused exponential
  Rosenbrock-Euler step (`frozen_advance`);
- `lanczos_tridiagonal`: its small eigenproblem: phi_p(T_m) e_1 and the error bound from the
  QL iteration on T_m;
- `lanczos_rule`: the Lanczos stopping rule's constants and scalar rules, plain Python (no
  numba): the one source that the compiled Lanczos compiles and the numpy Lanczos
  (`agent_envs.integrators.lanczos_stopping`) reads;
- `noise`: numpy's standard normals from many numpy generators in one call;
- `step`: the native vector env's prologue and epilogue around its fused pass.

`loader` imports them (numba) only when a path is asked for: `available(name)`, `loaded(name)`,
`use(name, on)`, `status()`, ``AGENT_ENVS_NUMBA=0`` (its docstring has the table of paths,
owners and checks), and runs the compiled passes on numba's threads (`call_on_threads`).
Importing this package imports no numba. The numpy code that each path replaces stays with
its owner (`agent_envs.dynamics.laplacian`, `agent_envs.integrators.phi_lanczos`,
`agent_envs.draws`, `agent_envs.envs.fast_step`), which is the reference the compiled
values are checked against.
"""

from agent_envs.native.loader import (
    ENV_VAR,
    PATHS,
    CompiledPath,
    available,
    call_on_threads,
    check_compiled_threads,
    compiled_threads,
    import_checked,
    import_compiled,
    load_compiled_threads,
    loaded,
    max_compiled_threads,
    register_check,
    status,
    use,
)

__all__ = [
    "ENV_VAR",
    "PATHS",
    "CompiledPath",
    "available",
    "call_on_threads",
    "check_compiled_threads",
    "compiled_threads",
    "import_checked",
    "import_compiled",
    "load_compiled_threads",
    "loaded",
    "max_compiled_threads",
    "register_check",
    "status",
    "use",
]
