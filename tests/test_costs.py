"""Running cost, discrete cost and turnpike distance against hand-computed values."""

import numpy as np

from agent_envs.costs import (
    agent_running_cost,
    discrete_cost,
    running_cost,
    turnpike_distance,
)


def test_running_cost_hand_value():
    # N = 3, d = 2, target (1, 0), gamma = 0.5
    x = np.array([[1.0, 0.0], [2.0, 0.0], [1.0, 2.0]])
    u = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 2.0]])
    target = np.array([1.0, 0.0])
    # per agent: |x - xbar|^2 = 0, 1, 4 ; gamma |u|^2 = 0, 1, 2
    np.testing.assert_allclose(agent_running_cost(x, u, target, 0.5), [0.0, 2.0, 6.0])
    assert running_cost(x, u, target, 0.5) == 8.0 / 3.0
    assert running_cost(x, None, target, 0.5) == 5.0 / 3.0


def test_discrete_cost_is_left_rectangle_rule_per_path():
    target = np.zeros(1)
    positions = np.array([[[[1.0]], [[2.0]]], [[[3.0]], [[0.0]]], [[[9.0]], [[9.0]]]])  # (3,2,1,1)
    controls = np.zeros((2, 2, 1, 1))
    # path 0: tau (1 + 9), path 1: tau (4 + 0); the last state (n = m) is not charged
    np.testing.assert_allclose(discrete_cost(positions, controls, target, 1.0, 0.5), [5.0, 2.0])


def test_turnpike_distance_hand_value():
    mean_x = np.array([[1.0], [3.0]])
    u = np.array([[2.0], [0.0]])
    assert turnpike_distance(mean_x, u, np.array([1.0])) == 4.0 + 4.0
