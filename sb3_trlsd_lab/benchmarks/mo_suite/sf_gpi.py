"""
Successor features with generalised policy improvement (Barreto et al., "Successor Features for Transfer in
Reinforcement Learning", NeurIPS 2017), linear on a feature map, learnt from transitions.

With a reward vector r_vec paid on each transition (the cumulant) and a task's reward w . r_vec, the
successor features of a policy pi are psi^pi(s, a) = E[sum_t gamma^t r_vec_t | s, a, pi], so that
Q^pi_w(s, a) = psi^pi(s, a) . w for every w. Here psi^pi(s, a) = Theta^T x(s, a) with x(s, a) the state
features f(s) in the block of action a, and Theta solves LSTD's fixed point on the transitions:

    sum_j x_j (x_j - gamma c_j x(s'_j, pi(s'_j)))^T Theta = sum_j x_j r_vec_j^T,   c_j = 0 if s'_j absorbs.

A source task's policy is found by least-squares policy iteration on its w_i (LSTD of the successor
features, then pi <- argmax_a psi(s, a) . w_i); a new task's w is regressed from its scalar rewards on the
reward vectors seen online, and GPI acts by argmax_a max_i psi^{pi_i}(s, a) . w. The maths are plain
functions over arrays; ``SuccessorFeaturesGPI`` keeps what an agent learns.
"""

from __future__ import annotations

import numpy as np

from sb3_trlsd.feature_maps import FeatureMap

__all__ = [
    "SuccessorFeaturesGPI",
    "gpi_q_values",
    "greedy_actions",
    "lstd_successor_features",
    "policy_iteration",
    "regress_weights",
    "successor_values",
]

RIDGE = 1e-3  # of LSTD's system, relative to its diagonal's mean: a feature no transition touches stays 0
WEIGHT_RIDGE = 1e-6  # of the online regression of w: w = 0 before any reward vector varies


def successor_values(features: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """
    psi(s, a) for every action: the successor features of states.

    :param features: f(s), (n, m)
    :param theta: (n_actions, m, k), the block of each action
    :return: (n, n_actions, k)
    """
    return np.einsum("nm,amk->nak", features, theta)


def greedy_actions(features: np.ndarray, theta: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """
    argmax_a psi(s, a) . w, the first action on ties.

    :param features: f(s), (n, m)
    :param theta: (n_actions, m, k)
    :param weights: w, (k,)
    :return: (n,)
    """
    return np.argmax(successor_values(features, theta) @ weights, axis=1)


def gpi_q_values(features: np.ndarray, thetas: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """
    GPI's values max_i psi^{pi_i}(s, a) . w.

    :param features: f(s), (n, m)
    :param thetas: (n_policies, n_actions, m, k)
    :param weights: w, (k,)
    :return: (n, n_actions)
    """
    q = np.einsum("nm,pamk,k->pna", features, thetas, weights)  # (n_policies, n, n_actions)
    return q.max(axis=0)


def lstd_successor_features(
    features: np.ndarray,
    actions: np.ndarray,
    cumulants: np.ndarray,
    next_features: np.ndarray,
    next_actions: np.ndarray,
    continues: np.ndarray,
    n_actions: int,
    gamma: float,
    ridge: float = RIDGE,
) -> np.ndarray:
    """
    LSTD's successor features of the policy that takes ``next_actions`` in the next states.

    The system is built block by block (each row touches the block of its action and that of its next
    action), in O(n m^2), without the (n, m * n_actions) design matrix.

    :param features: f(s_j), (n, m)
    :param actions: a_j, (n,)
    :param cumulants: r_vec_j, (n, k)
    :param next_features: f(s'_j), (n, m)
    :param next_actions: pi(s'_j), (n,)
    :param continues: 1 where s'_j is not absorbing, else 0, (n,)
    :param n_actions: |A|
    :param gamma: discount factor in [0, 1)
    :param ridge: Tikhonov term, relative to the mean of the system's diagonal
    :return: theta, (n_actions, m, k)
    """
    m = features.shape[1]
    k = cumulants.shape[1]
    system = np.zeros((n_actions, m, n_actions, m))
    target = np.zeros((n_actions, m, k))
    discounted = gamma * np.asarray(continues, dtype=np.float64)[:, None] * next_features  # (n, m)
    for a in range(n_actions):
        rows = actions == a
        f_a = features[rows]  # (n_a, m)
        system[a, :, a, :] += f_a.T @ f_a
        target[a] = f_a.T @ cumulants[rows]
        for b in range(n_actions):
            both = rows & (next_actions == b)
            if both.any():
                system[a, :, b, :] -= features[both].T @ discounted[both]
    matrix = system.reshape(n_actions * m, n_actions * m)
    scale = max(float(np.mean(np.diag(matrix))), 1e-12)
    matrix += ridge * scale * np.eye(n_actions * m)
    theta = np.linalg.solve(matrix, target.reshape(n_actions * m, k))
    return theta.reshape(n_actions, m, k)


def policy_iteration(
    features: np.ndarray,
    actions: np.ndarray,
    cumulants: np.ndarray,
    next_features: np.ndarray,
    continues: np.ndarray,
    weights: np.ndarray,
    n_actions: int,
    gamma: float,
    max_iterations: int = 10,
    ridge: float = RIDGE,
) -> np.ndarray:
    """
    Least-squares policy iteration on the task w: LSTD of the successor features of pi, then
    pi <- argmax_a psi(s, a) . w on the next states, until pi stops changing there (or ``max_iterations``).

    :param weights: the task's w, (k,)
    :param ridge: LSTD's Tikhonov term (see ``lstd_successor_features``)
    :return: theta of the last policy, (n_actions, m, k)
    """
    next_actions = np.zeros(len(actions), dtype=np.int64)  # the first policy: always action 0
    theta = np.zeros((n_actions, features.shape[1], cumulants.shape[1]))
    for _ in range(max_iterations):
        theta = lstd_successor_features(
            features, actions, cumulants, next_features, next_actions, continues, n_actions, gamma, ridge
        )
        improved = greedy_actions(next_features, theta, weights)
        if np.array_equal(improved, next_actions):
            break
        next_actions = improved
    return theta


def regress_weights(gram: np.ndarray, moment: np.ndarray, ridge: float = WEIGHT_RIDGE) -> np.ndarray:
    """
    The least-squares w of r = w . r_vec, from sum r_vec r_vec^T and sum r_vec r.

    :param gram: sum_t r_vec_t r_vec_t^T, (k, k)
    :param moment: sum_t r_vec_t r_t, (k,)
    :param ridge: Tikhonov term (w = 0 with no data)
    :return: w, (k,)
    """
    return np.linalg.solve(gram + ridge * np.eye(len(moment)), moment)


class SuccessorFeaturesGPI:
    """
    An agent that acts by GPI over the successor features of source policies, for a task whose w it
    regresses online from the scalar rewards and the reward vectors it sees.

    :param features: the state features f
    :param thetas: the successor features of the source policies, (n_policies, n_actions, m, k)
    :param seed: seed of the tie breaks (all actions tie before any reward vector varies)
    """

    def __init__(self, features: FeatureMap, thetas: np.ndarray, seed: int = 0) -> None:
        self.features = features
        self.thetas = np.asarray(thetas, dtype=np.float64)
        k = self.thetas.shape[-1]
        self.gram = np.zeros((k, k))
        self.moment = np.zeros(k)
        self.weights = np.zeros(k)
        self.rng = np.random.default_rng(seed)

    @classmethod
    def from_source(
        cls,
        features: FeatureMap,
        states: np.ndarray,
        actions: np.ndarray,
        vector_rewards: np.ndarray,
        next_states: np.ndarray,
        terminations: np.ndarray,
        source_weights: np.ndarray,
        n_actions: int,
        gamma: float,
        seed: int = 0,
    ) -> SuccessorFeaturesGPI:
        """
        Learn each source task's policy and its successor features from the transitions (all of them, of
        every source task: the cumulant and the dynamics are shared).

        :param source_weights: w of each source task, (n_policies, k)
        """
        f, f_next = features(states), features(next_states)
        continues = 1.0 - np.asarray(terminations, dtype=np.float64)
        thetas = [
            policy_iteration(f, actions, vector_rewards, f_next, continues, w, n_actions, gamma)
            for w in np.asarray(source_weights, dtype=np.float64)
        ]
        return cls(features, np.stack(thetas), seed)

    def act(self, state: np.ndarray) -> int:
        """GPI's action in ``state`` for the current estimate of w, ties broken at random."""
        q = gpi_q_values(self.features(np.asarray(state, dtype=np.float64)[None]), self.thetas, self.weights)[
            0
        ]
        best = np.flatnonzero(q >= q.max() - 1e-12)
        return int(self.rng.choice(best))

    def observe(self, vector_reward: np.ndarray, reward: float) -> None:
        """Add one step's reward vector and scalar reward to the regression of w, and update w."""
        vector = np.asarray(vector_reward, dtype=np.float64)
        self.gram += np.outer(vector, vector)
        self.moment += vector * float(reward)
        self.weights = regress_weights(self.gram, self.moment)
