"""Every invalid SwarmParams value raises a clear error naming the field."""

import math

import pytest

from agent_envs import SwarmParams


@pytest.mark.parametrize(
    ("field", "value", "error"),
    [
        ("n_agents", 1, ValueError),
        ("n_agents", 2.5, TypeError),
        ("n_agents", True, TypeError),
        ("dim", 0, ValueError),
        ("kernel", "banana", ValueError),
        ("kernel", object(), TypeError),
        ("alpha", 0.0, ValueError),
        ("alpha", -1.0, ValueError),
        ("epsilon", -0.05, ValueError),
        ("epsilon", math.nan, ValueError),
        ("epsilon_min", 0.0, ValueError),
        ("epsilon_max", math.inf, ValueError),
        ("sigma", -0.1, ValueError),
        ("sigma", "0.1", TypeError),
        ("horizon", 0.0, ValueError),
        ("target", [1.0, 2.0], ValueError),
        ("target", math.nan, ValueError),
        ("gamma", -1.0, ValueError),
    ],
)
def test_invalid_field_raises_naming_it(field, value, error):
    with pytest.raises(error, match=field):
        SwarmParams(**{field: value})


def test_epsilon_range_must_be_ordered():
    with pytest.raises(ValueError, match="epsilon_max must be >= epsilon_min"):
        SwarmParams(epsilon_min=0.2, epsilon_max=0.1)


def test_valid_params_are_normalised_and_frozen():
    p = SwarmParams(n_agents=5, dim=2, target=[0.5, -1], sigma=0)
    assert p.target == (0.5, -1.0)
    assert p.target_vector.shape == (2,)
    assert isinstance(p.sigma, float)
    with pytest.raises(AttributeError):
        p.sigma = 1.0  # type: ignore[misc]
    assert SwarmParams(dim=3, target=0.2).target == (0.2, 0.2, 0.2)


def test_user_kernel_must_say_whether_it_is_symmetric():
    class NoFlag:
        def value(self, xk, xl): ...

        def grad_x(self, xk, xl): ...

        def grad_y(self, xk, xl): ...

    with pytest.raises(TypeError, match="symmetric"):
        SwarmParams(kernel=NoFlag())
