"""simulate's input contract and defaults, test by test from the mutation run (docs/mutation.md):
shapes accepted and refused with messages naming them, the eigh checks, the batch limit, the
divergence threshold, torch inputs, the integrator-instance conflicts."""

import numpy as np
import pytest

from agent_envs import SwarmParams, simulate


@pytest.mark.parametrize("integrator", ["erb", "serb"])
def test_eigh_is_refused_for_a_non_symmetric_matrix_and_auto_is_not(integrator):
    """phi_method="eigh" needs a symmetric L (frozen) or a symmetric radial kernel (exact):
    refused with the non-symmetric kernel, naming phi_method; "auto" and "expm" run."""
    params = SwarmParams(n_agents=4, kernel="nonsymmetric")
    for jacobian in ("frozen", "exact"):
        with pytest.raises(ValueError, match="phi_method='eigh' needs a symmetric"):
            simulate(params, integrator, jacobian=jacobian, phi_method="eigh", n_steps=2)
        for method in ("auto", "expm"):  # run (the exact Jacobian may diverge at m = 2)
            traj = simulate(params, integrator, jacobian=jacobian, phi_method=method, n_steps=2)
            assert traj.positions.shape == (3, 20, 4, 1)
    # a symmetric kernel takes eigh with either Jacobian
    symmetric = SwarmParams(n_agents=4)
    for jacobian in ("frozen", "exact"):
        simulate(symmetric, integrator, jacobian=jacobian, phi_method="eigh", n_steps=2)
    # the explicit schemes have no phi-functions: eigh is not checked against the kernel
    simulate(params, "em", phi_method="eigh", n_steps=2)


class _SymmetricUserKernel:
    """A user kernel p = 1 / (1 + |x - y|^2) that says it is symmetric but not radial."""

    symmetric = True

    def value(self, xk, xl):
        return 1.0 / (1.0 + ((xl - xk) ** 2).sum(axis=-1))

    def grad_x(self, xk, xl):
        r = xl - xk
        return (2.0 / (1.0 + (r**2).sum(axis=-1)) ** 2)[..., None] * r

    def grad_y(self, xk, xl):
        return -self.grad_x(xk, xl)


def test_eigh_with_a_symmetric_user_kernel_that_is_not_radial():
    """The frozen L(x) of a symmetric kernel is symmetric (eigh allowed); its exact Jacobian is
    symmetric only for a radial kernel, which this one does not declare (eigh refused)."""
    params = SwarmParams(n_agents=4, kernel=_SymmetricUserKernel())
    simulate(params, "serb", jacobian="frozen", phi_method="eigh", n_steps=2)
    with pytest.raises(ValueError, match="phi_method='eigh'"):
        simulate(params, "serb", jacobian="exact", phi_method="eigh", n_steps=2)


def test_shapes_the_contract_accepts_and_names():
    params1, params2 = SwarmParams(n_agents=4), SwarmParams(n_agents=4, dim=2)
    x0 = np.linspace(-0.5, 0.5, 4)
    a = simulate(params1, "em", n_steps=3, n_paths=2, seed=1, initial_positions=x0)
    b = simulate(params1, "em", n_steps=3, n_paths=2, seed=1, initial_positions=x0[:, None])
    np.testing.assert_array_equal(a.positions, b.positions)  # (N,) and (N, 1) in d = 1
    u = np.full((3, 4), 0.5)
    c = simulate(params1, "em", n_steps=3, n_paths=2, seed=1, initial_positions=x0, control=u)
    d = simulate(
        params1, "em", n_steps=3, n_paths=2, seed=1, initial_positions=x0, control=u[..., None]
    )
    np.testing.assert_array_equal(c.positions, d.positions)  # control (m, N) in d = 1
    with pytest.raises(ValueError, match=r"\(4,\) or \(4, 1\)"):
        simulate(params1, initial_positions=np.zeros(5))
    with pytest.raises(ValueError, match=r"must have shape \(4, 2\), got \(4,\)"):
        simulate(params2, initial_positions=np.zeros(4))
    for shape in [(3, 3, 4, 1), (3, 1, 4, 1), (4, 2, 4, 1)]:
        with pytest.raises(ValueError, match="increments must have shape"):
            simulate(params1, n_steps=3, n_paths=2, increments=np.zeros(shape))
    default = simulate(params1, "em", n_paths=1, seed=0)  # n_steps = 50 by default
    assert default.times.shape == (51,) and default.positions.shape == (51, 1, 4, 1)
    assert simulate(params1, "em", n_steps=1, seed=0).positions.shape[1] == 20  # n_paths


def test_torch_inputs_must_be_real_floating_point():
    torch = pytest.importorskip("torch")
    params = SwarmParams(n_agents=4)
    for bad in (torch.zeros(4, dtype=torch.int64), torch.zeros(4, dtype=torch.complex128)):
        with pytest.raises(TypeError, match="initial_positions must be a real floating"):
            simulate(params, initial_positions=bad, n_steps=1)
    traj = simulate(params, initial_positions=torch.zeros(4, dtype=torch.float64), n_steps=1)
    assert isinstance(traj.positions, torch.Tensor)


def test_per_path_controls_and_wrong_control_shapes():
    params = SwarmParams(n_agents=4)
    u = np.random.default_rng(0).normal(size=(3, 2, 4, 1))  # (m, n_paths, N, d)
    traj = simulate(params, "em", n_steps=3, n_paths=2, seed=0, control=u)
    np.testing.assert_array_equal(traj.controls, u)
    for shape in [(3, 3, 1), (3, 5, 1), (2, 4, 1), (4, 4, 1), (3, 2, 1, 4, 1)]:
        with pytest.raises(ValueError, match="control must be None, a callable"):
            simulate(params, "em", n_steps=3, n_paths=2, control=np.zeros(shape))


def test_batch_size_limit_names_n_paths_times_n_times_d():
    """n_paths N d <= 1e8: 101 paths of 10^6 agents are refused before anything is drawn
    (the wrong-shaped increments would be refused next, with another message)."""
    params = SwarmParams(n_agents=10**6, epsilon=1.0)
    with pytest.raises(ValueError, match=r"n_paths \* N \* d"):
        simulate(params, n_steps=1, n_paths=101, increments=np.zeros((1, 1, 1, 1)))
    wide = SwarmParams(n_agents=5 * 10**6, dim=2, epsilon=1.0)  # N d = 10^7: 11 paths too many
    with pytest.raises(ValueError, match=r"n_paths \* N \* d"):
        simulate(wide, n_steps=1, n_paths=11, increments=np.zeros((1, 1, 1, 1)))


def test_positions_on_the_threshold_are_inside_and_mean_positions_averages_paths():
    """|x| <= R is inside (the message says so); mean_positions is E x^n over the paths."""
    params = SwarmParams(n_agents=4, epsilon=1.0, sigma=0.0)
    x0 = np.array([5.0, -5.0, 0.0, 1.0])
    traj = simulate(
        params, "em", n_steps=1, n_paths=3, seed=0, initial_positions=x0, divergence_threshold=5.0
    )
    np.testing.assert_array_equal(traj.positions[0, :, :, 0], np.tile(x0, (3, 1)))
    with pytest.raises(ValueError, match=r"\|x\| <= 5"):
        simulate(params, initial_positions=x0 * 1.01, divergence_threshold=5.0)
    noisy = simulate(SwarmParams(n_agents=4), "em", n_steps=2, n_paths=3, seed=0)
    assert noisy.mean_positions.shape == (3, 4, 1)
    np.testing.assert_array_equal(noisy.mean_positions, noisy.positions.mean(axis=1))


def test_a_control_callable_of_the_wrong_shape_is_named():
    params = SwarmParams(n_agents=4)
    with pytest.raises(ValueError, match="control at step 0 has shape"):
        simulate(params, "em", n_steps=2, control=lambda t, x: np.zeros(3))
    torch = pytest.importorskip("torch")
    x0 = torch.zeros(4, dtype=torch.float64)
    with pytest.raises(ValueError, match="control at step 0 has shape"):
        simulate(
            params,
            "em",
            n_steps=2,
            initial_positions=x0,
            control=lambda t, x: torch.zeros(3, dtype=torch.float64),
        )


def test_more_contract_details():
    """Defaults and messages the mutation run found unchecked: R = 1e4 by default (|x| <= R
    inside), a scalar start refused, a callable's control checked for a real dtype, the shape
    a 2-D control was given in, params kept out of the repr, linear_operator only with the
    default model, the batch limit counting N d (not N^d), the wall time measured."""
    import time

    from agent_envs import SwarmModel

    params = SwarmParams(n_agents=4)
    simulate(params, "em", n_steps=1, initial_positions=[1e4, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="divergence threshold"):
        simulate(params, "em", n_steps=1, initial_positions=[1.0001e4, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="initial_positions"):
        simulate(params, initial_positions=0.5)
    for bad in ("a", 1j):
        with pytest.raises(TypeError, match="control at step 0"):
            simulate(params, "em", n_steps=2, control=lambda t, x, bad=bad: bad)
    with pytest.raises(ValueError, match=r"got shape \(2, 4\)"):
        simulate(params, "em", n_steps=3, control=np.zeros((2, 4)))
    began = time.perf_counter()
    traj = simulate(params, "em", n_steps=2, n_paths=2, seed=0, linear_operator="dense")
    assert 0.0 < traj.wall_time <= time.perf_counter() - began
    assert "params=" not in repr(traj)
    with pytest.raises(ValueError, match="linear_operator applies to the default SwarmModel"):
        simulate(params, n_steps=1, model=SwarmModel(params), linear_operator="dense")
    wide = SwarmParams(n_agents=10**4, dim=2, epsilon=1.0)  # 2 paths x N d = 4e4 <= 1e8
    with pytest.raises(ValueError, match="increments must have shape"):
        simulate(wide, n_steps=1, n_paths=2, increments=np.zeros((1, 1, 1, 1)))
