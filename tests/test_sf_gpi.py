"""Successor features and GPI (``experiments/mo_suite/sf_gpi.py``) against closed forms on a small chain."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_trlsd_lab.benchmarks.mo_suite.sf_gpi import (
    SuccessorFeaturesGPI,
    gpi_q_values,
    lstd_successor_features,
    policy_iteration,
    regress_weights,
    successor_values,
)

N_STATES = 4
LEFT, RIGHT = 0, 1
GAMMA = 0.9


class OneHot:
    """One-hot features of the chain's states, as a ``FeatureMap`` is called."""

    n_features = N_STATES

    def __call__(self, states: np.ndarray) -> np.ndarray:
        return np.eye(N_STATES)[np.asarray(states, dtype=int).reshape(-1)]


def chain_step(state: int, action: int) -> int:
    """A 4-state chain: LEFT moves down (stops at 0), RIGHT moves up (stops at 3)."""
    return max(state - 1, 0) if action == LEFT else min(state + 1, N_STATES - 1)


def cumulant(next_state: int) -> np.ndarray:
    """Two objectives: being at the left end, being at the right end (paid on arrival)."""
    return np.array([next_state == 0, next_state == N_STATES - 1], dtype=np.float64)


def every_transition() -> tuple[np.ndarray, ...]:
    """Every (s, a) of the chain once, with its s' and reward vector: LSTD's fixed point is then exact."""
    states, actions = np.meshgrid(np.arange(N_STATES), [LEFT, RIGHT], indexing="ij")
    states, actions = states.reshape(-1), actions.reshape(-1)
    next_states = np.array([chain_step(s, a) for s, a in zip(states, actions, strict=True)])
    vectors = np.stack([cumulant(s) for s in next_states])
    return states, actions, next_states, vectors


def closed_form(policy: np.ndarray) -> np.ndarray:
    """psi^pi(s, pi(s)) = (I - gamma P_pi)^-1 r_pi: the state successor features, (N_STATES, 2)."""
    transition = np.zeros((N_STATES, N_STATES))
    rewards = np.zeros((N_STATES, 2))
    for s in range(N_STATES):
        transition[s, chain_step(s, policy[s])] = 1.0
        rewards[s] = cumulant(chain_step(s, policy[s]))
    return np.linalg.solve(np.eye(N_STATES) - GAMMA * transition, rewards)


@pytest.mark.parametrize("policy", [[LEFT] * 4, [RIGHT] * 4, [LEFT, RIGHT, LEFT, RIGHT]], ids=str)
def test_lstd_successor_features_equal_the_closed_form_of_a_fixed_policy(policy):
    """With one-hot features and every transition once, LSTD is (I - gamma P_pi)^-1 r_pi: a wrong Bellman
    target (next action, discount, termination mask or block layout) would move it."""
    policy = np.array(policy)
    states, actions, next_states, vectors = every_transition()
    features = OneHot()
    theta = lstd_successor_features(
        features(states),
        actions,
        vectors,
        features(next_states),
        policy[next_states],
        np.ones(len(states)),
        n_actions=2,
        gamma=GAMMA,
        ridge=0.0,
    )
    psi = successor_values(features(np.arange(N_STATES)), theta)  # (N_STATES, 2 actions, 2 objectives)
    np.testing.assert_allclose(psi[np.arange(N_STATES), policy], closed_form(policy), atol=1e-10)


def test_lstd_stops_at_absorbing_states():
    """A terminal transition pays its cumulant once: psi(s, a) = r_vec when s' absorbs."""
    features = OneHot()
    states, actions, next_states, vectors = every_transition()
    theta = lstd_successor_features(
        features(states),
        actions,
        vectors,
        features(next_states),
        np.zeros(len(states), dtype=int),
        np.zeros(len(states)),
        n_actions=2,
        gamma=GAMMA,
        ridge=0.0,
    )
    psi = successor_values(features(states), theta)[np.arange(len(states)), actions]
    np.testing.assert_allclose(psi, vectors, atol=1e-10)


def test_policy_iteration_finds_the_optimal_policy_of_each_task():
    """Policy iteration on w = (1, 0) goes left everywhere, on w = (0, 1) right: its values equal the closed
    form of those policies."""
    features = OneHot()
    states, actions, next_states, vectors = every_transition()
    args = (features(states), actions, vectors, features(next_states), np.ones(len(states)))
    for weights, best in (((1.0, 0.0), LEFT), ((0.0, 1.0), RIGHT)):
        theta = policy_iteration(*args, np.array(weights), n_actions=2, gamma=GAMMA, ridge=0.0)
        q = successor_values(features(np.arange(N_STATES)), theta) @ np.array(weights)
        assert np.all(np.argmax(q, axis=1) == best)
        np.testing.assert_allclose(q.max(axis=1), closed_form(np.full(N_STATES, best)) @ weights, atol=1e-8)


def test_gpi_takes_the_better_policy_for_a_new_task():
    """GPI over 'always left' and 'always right' for w = (0.2, 0.8): its value is the max of the two policies'
    values, and it picks the better policy's action (right) where right's value is higher."""
    features = OneHot()
    states, actions, next_states, vectors = every_transition()
    thetas = np.stack(
        [
            lstd_successor_features(
                features(states),
                actions,
                vectors,
                features(next_states),
                np.full(len(states), side),
                np.ones(len(states)),
                n_actions=2,
                gamma=GAMMA,
                ridge=0.0,
            )
            for side in (LEFT, RIGHT)
        ]
    )
    weights = np.array([0.2, 0.8])
    q = gpi_q_values(features(np.arange(N_STATES)), thetas, weights)
    each = np.stack([successor_values(features(np.arange(N_STATES)), theta) @ weights for theta in thetas])
    np.testing.assert_allclose(q, each.max(axis=0))
    assert np.all(np.argmax(q, axis=1) == RIGHT)


def test_regress_weights_recovers_w_and_the_agent_learns_it_online():
    """The online regression of r on r_vec finds w exactly from noise-free rewards, and the agent's GPI
    action follows it (left for w = (1, 0))."""
    rng = np.random.default_rng(0)
    vectors = rng.normal(size=(50, 3))
    weights = np.array([0.5, -1.0, 2.0])
    np.testing.assert_allclose(
        regress_weights(vectors.T @ vectors, vectors.T @ (vectors @ weights)), weights, atol=1e-6
    )
    features = OneHot()
    states, actions, next_states, vectors = every_transition()
    agent = SuccessorFeaturesGPI.from_source(
        features,
        states,
        actions,
        vectors,
        next_states,
        np.zeros(len(states), dtype=bool),
        source_weights=np.array([[1.0, 0.0], [0.0, 1.0]]),
        n_actions=2,
        gamma=GAMMA,
    )
    for vector in ([1.0, 0.0], [0.0, 1.0], [0.0, 0.0]):
        agent.observe(np.array(vector), reward=float(np.array(vector) @ [1.0, 0.0]))
    np.testing.assert_allclose(agent.weights, [1.0, 0.0], atol=1e-5)
    assert [agent.act(np.array([s])) for s in range(1, N_STATES)] == [LEFT] * (N_STATES - 1)
