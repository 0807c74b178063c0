"""Reward heads with other confidence bounds against their closed forms: OFUL's ellipsoid, Thompson, UCB-V."""

import copy
import pickle

import gymnasium as gym
import numpy as np
import pytest

from sb3_trlsd import TRLSD
from sb3_trlsd.feature_maps import RBFGrid
from sb3_trlsd.reward_heads import (
    BernsteinRewardHead,
    BernsteinTracker,
    PosteriorTracker,
    RidgePosteriorRewardHead,
    ThompsonRidgeRewardHead,
    make_reward_head,
)
from sb3_trlsd.reward_heads.posterior import sample_posterior_weights
from tests.conftest import MAZE_ID

LINE = RBFGrid(low=(0,), high=(1,), n_per_dim=4, sigma=0.3)  # k = 4 features on [0, 1]
MAZE_GRID = RBFGrid(low=(0, 0), high=(5, 5), n_per_dim=5, sigma=0.04)  # the paper's features
RIDGE = 0.5  # not 1, so that a lambda left out or misplaced shows
# Rounding of a few hundred products and sums in different orders.
RTOL = 1e-9


def line_samples(n, seed=0):
    """n states uniform on [0, 1] and noisy rewards of a smooth function."""
    rng = np.random.default_rng(seed)
    states = rng.uniform(0, 1, size=(n, 1))
    return states, np.sin(3 * states[:, 0]) + 0.3 * rng.normal(size=n)


def fed(head, states, rewards, n_chunks=3):
    """The head after updates in ``n_chunks`` chunks (incremental sums must equal the batch closed form)."""
    for chunk in np.array_split(np.arange(len(states)), n_chunks):
        head.update(states[chunk], rewards[chunk])
    return head


def gram_by_hand(states, ridge=RIDGE, features=LINE):
    phi = features(states)
    return phi.T @ phi + ridge * np.eye(phi.shape[1])


def widths_by_hand(queries, gram, features=LINE):
    """sqrt(phi^T A^-1 phi), query by query, through a linear solve."""
    return np.array([np.sqrt(phi @ np.linalg.solve(gram, phi)) for phi in features(queries)])


def bernstein_by_hand(sample_states, rewards, query, kappa, sigma, reward_range, w_floor=1e-6):
    """R^ and CI of UCB-V kernel-weighted, written out sample by sample."""
    weights = [np.exp(-np.sum((query - s) ** 2) / (2 * sigma**2)) for s in sample_states]
    total = max(sum(weights), w_floor)
    mean = sum(w * r for w, r in zip(weights, rewards, strict=True)) / total
    variance = sum(w * r**2 for w, r in zip(weights, rewards, strict=True)) / total - mean**2
    log_count = np.log(max(len(rewards), 2))
    width = np.sqrt(2 * variance * log_count / total) + 3 * reward_range * log_count / total
    return mean, kappa * width


def all_beyond_heads():
    """One head of each kind, with readable ids (factories: each test gets a fresh head)."""
    return [
        pytest.param(lambda: RidgePosteriorRewardHead(LINE, kappa=0.4, ridge=RIDGE), id="ridge_posterior"),
        pytest.param(lambda: ThompsonRidgeRewardHead(LINE, kappa=0.4, ridge=RIDGE, seed=3), id="thompson"),
        pytest.param(lambda: BernsteinRewardHead(kappa=0.4, sigma=0.1, reward_range=2.0), id="bernstein"),
    ]


# ----------------------------------------------------------------------------------- OFUL / LinUCB ellipsoid
def test_posterior_head_is_tikhonov_least_squares_with_the_ellipsoidal_width():
    """R^ is lstsq on [Phi; sqrt(lambda) I] w = [r; 0]; CI is kappa sqrt(phi^T A^-1 phi) by linalg.solve."""
    states, rewards = line_samples(40)
    head = fed(RidgePosteriorRewardHead(LINE, kappa=0.4, ridge=RIDGE), states, rewards)
    tikhonov_rows = np.vstack([LINE(states), np.sqrt(RIDGE) * np.eye(4)])
    weights = np.linalg.lstsq(tikhonov_rows, np.concatenate([rewards, np.zeros(4)]), rcond=None)[0]
    queries = np.linspace(-0.2, 1.2, 9).reshape(-1, 1)
    widths = widths_by_hand(queries, gram_by_hand(states))
    np.testing.assert_allclose(head.estimate(queries), LINE(queries) @ weights, rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(head.uncertainty(queries), widths, rtol=RTOL)
    np.testing.assert_allclose(head.bonus(queries), 0.4 * widths, rtol=RTOL)
    np.testing.assert_allclose(head.optimistic(queries), LINE(queries) @ weights + 0.4 * widths, rtol=RTOL)
    capped = fed(RidgePosteriorRewardHead(LINE, kappa=0.4, ridge=RIDGE, r_max=0.5), states, rewards)
    np.testing.assert_allclose(capped.optimistic(queries), np.minimum(head.optimistic(queries), 0.5))


def test_posterior_uncertainty_then_and_now_are_the_widths_of_each_gram():
    """The snapshot keeps A^-1 of its moment: later samples change the width now, not the width then."""
    states, rewards = line_samples(30, seed=1)
    queries = np.array([[0.1], [0.5], [0.95]])
    head = RidgePosteriorRewardHead(LINE, kappa=0.4, ridge=RIDGE)
    before_any = head.snapshot()
    head.update(states[:10], rewards[:10])
    after_ten = head.snapshot()
    fed(head, states[10:], rewards[10:])
    then, now = head.uncertainty_then_and_now(after_ten, queries)
    np.testing.assert_allclose(then, widths_by_hand(queries, gram_by_hand(states[:10])), rtol=RTOL)
    np.testing.assert_allclose(now, widths_by_hand(queries, gram_by_hand(states)), rtol=RTOL)
    np.testing.assert_allclose(head.uncertainty_as_of(after_ten, queries), then, rtol=RTOL)
    prior_widths = np.sqrt(np.sum(LINE(queries) ** 2, axis=1) / RIDGE)  # A = lambda I
    np.testing.assert_allclose(head.uncertainty_as_of(before_any, queries), prior_widths, rtol=RTOL)
    assert np.all(now < then)


@pytest.mark.parametrize("head_class", [RidgePosteriorRewardHead, ThompsonRidgeRewardHead])
def test_determinant_rule_fires_exactly_once_det_has_grown_by_the_ratio(head_class):
    """refit_due is log det A_now - log det A_then >= log(update_ratio), A's log det by slogdet by hand."""
    states, rewards = line_samples(25, seed=2)
    head = head_class(LINE, kappa=0.4, ridge=RIDGE)
    prior = head.snapshot()
    head.update(states[:5], rewards[:5])
    at_refit = head.snapshot()
    head.update(states[5:], rewards[5:])
    state = states[-1]
    for then_states, snapshot in ((states[:5], at_refit), (states[:0], prior)):
        growth = np.exp(
            np.linalg.slogdet(gram_by_hand(states))[1] - np.linalg.slogdet(gram_by_hand(then_states))[1]
        )
        assert growth > 1.5  # a ratio worth testing on both sides
        assert head.refit_due(snapshot, state, update_ratio=growth * (1 - 1e-6))
        assert not head.refit_due(snapshot, state, update_ratio=growth * (1 + 1e-6))
    assert not head_class(LINE).refit_due(prior, state, update_ratio=2.0)  # no sample: A is still lambda I


# ------------------------------------------------------------------------------------------ Thompson (PSRL)
def test_thompson_draws_have_the_posterior_mean_and_covariance():
    """
    20,000 draws of w~ have mean w_hat and covariance v^2 A^-1 within 5 standard errors per entry: a draw
    from v A^-1 (v, not v^2) or from A instead of A^-1 misses by far more on this A (eigenvalues ~0.5 to ~15).
    """
    states, rewards = line_samples(30, seed=4)
    features = RBFGrid(low=(0,), high=(1,), n_per_dim=3, sigma=0.3)
    gram = gram_by_hand(states, features=features)
    weights = np.linalg.solve(gram, features(states).T @ rewards)
    scale, n_draws = 0.5, 20_000
    draws = sample_posterior_weights(np.random.default_rng(0), weights, gram, scale, n_draws)
    covariance = scale**2 * np.linalg.inv(gram)
    mean_se = np.sqrt(np.diag(covariance) / n_draws)
    np.testing.assert_array_less(np.abs(draws.mean(axis=0) - weights), 5 * mean_se)
    # se of a sample covariance entry of a Gaussian: sqrt((S_ii S_jj + S_ij^2) / n)
    covariance_se = np.sqrt((np.outer(np.diag(covariance), np.diag(covariance)) + covariance**2) / n_draws)
    np.testing.assert_array_less(np.abs(np.cov(draws.T) - covariance), 5 * covariance_se)


def test_thompson_draws_once_per_refit_from_the_posterior_of_that_moment():
    """
    Same seed, same draw; the draw holds through updates until a refit (snapshot) is followed by a sample;
    the next one is N(w_hat, v^2 A^-1) of the posterior as of the read, with the generator's next normals.
    """
    states, rewards = line_samples(30, seed=5)
    queries = np.linspace(0, 1, 7).reshape(-1, 1)
    head = fed(ThompsonRidgeRewardHead(LINE, kappa=0.6, ridge=RIDGE, seed=11), states[:10], rewards[:10])
    twin = fed(ThompsonRidgeRewardHead(LINE, kappa=0.6, ridge=RIDGE, seed=11), states[:10], rewards[:10])
    other = fed(ThompsonRidgeRewardHead(LINE, kappa=0.6, ridge=RIDGE, seed=12), states[:10], rewards[:10])
    first_fit = head.optimistic(queries)
    np.testing.assert_array_equal(twin.optimistic(queries), first_fit)
    assert not np.allclose(other.optimistic(queries), first_fit)
    replica = np.random.default_rng(11)
    np.testing.assert_allclose(
        first_fit,
        LINE(queries) @ sample_posterior_weights(replica, head.weights, gram_by_hand(states[:10]), 0.6)[0],
        rtol=RTOL,
    )
    head.update(states[10:20], rewards[10:20])  # samples between two refits: FQI's reward stays the same
    np.testing.assert_array_equal(head.optimistic(queries), first_fit)
    head.snapshot()  # the refit: a picture of it still shows the fit's draw
    np.testing.assert_array_equal(head.optimistic(queries), first_fit)
    head.update(states[20:], rewards[20:])
    second_fit = head.optimistic(queries)
    expected = sample_posterior_weights(replica, head.weights, gram_by_hand(states), 0.6)[0]
    np.testing.assert_allclose(second_fit, LINE(queries) @ expected, rtol=RTOL)
    np.testing.assert_allclose(
        head.bonus(queries), second_fit - head.estimate(queries), rtol=RTOL, atol=1e-12
    )
    head.resample()
    assert not np.allclose(head.optimistic(queries), second_fit)


def test_thompson_with_zero_scale_is_the_posterior_mean():
    """kappa = v = 0 is the non-optimistic method: R~ = R^, and no draw is made."""
    states, rewards = line_samples(20, seed=6)
    head = fed(ThompsonRidgeRewardHead(LINE, kappa=0.0, seed=0), states, rewards)
    np.testing.assert_array_equal(head.optimistic(states), head.estimate(states))
    assert head._sampled_weights is None


def test_thompson_scaled_by_the_observed_rewards_scales_its_draws_with_them():
    """
    kappa_scale="observed": v = kappa x the largest |reward| seen, so rewards times c give R~ times c (the
    same normals); before a nonzero reward v is kappa, and kappa_scale="reward" keeps v = kappa throughout.
    """
    states, rewards = line_samples(20, seed=7)
    queries = np.linspace(0, 1, 9).reshape(-1, 1)
    draws = {}
    for c in (1.0, 100.0):
        head = fed(
            ThompsonRidgeRewardHead(LINE, kappa=0.2, seed=5, kappa_scale="observed"), states, c * rewards
        )
        assert head.posterior_scale == pytest.approx(0.2 * c * np.abs(rewards).max())
        draws[c] = head.optimistic(queries)
    np.testing.assert_allclose(draws[100.0], 100.0 * draws[1.0], rtol=RTOL)
    silent = fed(ThompsonRidgeRewardHead(LINE, kappa=0.2, kappa_scale="observed"), states, 0 * rewards)
    in_reward_units = fed(ThompsonRidgeRewardHead(LINE, kappa=0.2), states, 100.0 * rewards)
    assert silent.posterior_scale == 0.2 and in_reward_units.posterior_scale == 0.2


# ------------------------------------------------------------------------------- UCB-V, kernel-weighted
def test_bernstein_head_is_the_kernel_mean_and_the_empirical_bernstein_width():
    """On 4 samples, R^ and CI are the kernel-weighted mean and UCB-V's width written out by hand."""
    sample_states = np.array([[0.0], [0.1], [0.5], [1.0]])
    rewards = np.array([1.0, 0.0, 0.5, 2.0])
    head = fed(BernsteinRewardHead(kappa=0.7, sigma=0.3, reward_range=2.0), sample_states, rewards, 2)
    queries = np.array([[0.05], [0.9], [40.0]])  # the last one has W = 0: the floor decides
    by_hand = np.array([bernstein_by_hand(sample_states, rewards, q, 0.7, 0.3, 2.0) for q in queries])
    np.testing.assert_allclose(head.estimate(queries), by_hand[:, 0], rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(head.bonus(queries), by_hand[:, 1], rtol=RTOL)
    np.testing.assert_allclose(head.optimistic(queries), by_hand.sum(axis=1), rtol=RTOL)
    np.testing.assert_allclose(head.bonus(queries[2:]), 0.7 * 3 * 2.0 * np.log(4) / 1e-6, rtol=RTOL)
    then, now = head.uncertainty_then_and_now(2, queries[:2])
    then_by_hand = [
        bernstein_by_hand(sample_states[:2], rewards[:2], q, 1.0, 0.3, 2.0)[1] for q in queries[:2]
    ]
    np.testing.assert_allclose(then, then_by_hand, rtol=RTOL)
    np.testing.assert_allclose(now, by_hand[:2, 1] / 0.7, rtol=RTOL)


def test_bernstein_width_shrinks_where_neighbours_agree():
    """Same states, same mean reward: agreeing rewards (V = 0) get a smaller CI than disagreeing ones."""
    states = np.full((6, 1), 0.5)
    agreeing = fed(BernsteinRewardHead(sigma=0.2), states, np.full(6, 0.5))
    disagreeing = fed(BernsteinRewardHead(sigma=0.2), states, np.array([0.0, 1.0] * 3))
    query = np.array([[0.5]])
    np.testing.assert_allclose(agreeing.estimate(query), disagreeing.estimate(query), rtol=RTOL)
    np.testing.assert_allclose(agreeing.bonus(query), 0.1 * 3 * np.log(6) / 6, rtol=RTOL)
    np.testing.assert_allclose(
        disagreeing.bonus(query) - agreeing.bonus(query), 0.1 * np.sqrt(2 * 0.25 * np.log(6) / 6), rtol=RTOL
    )


# ------------------------------------------------------------------------------ what every new head shares
@pytest.mark.parametrize("make_head", all_beyond_heads())
def test_tracker_equals_the_head_after_incremental_updates(make_head):
    """tracker.optimistic() (and R^, CI) is the head evaluated on the tracked states, after each step."""
    head = make_head()
    states, rewards = line_samples(60, seed=7)
    queries = np.random.default_rng(8).uniform(-0.1, 1.1, size=(40, 1))
    tracker = head.tracker(queries[:10])
    assert isinstance(
        tracker, BernsteinTracker if isinstance(head, BernsteinRewardHead) else PosteriorTracker
    )
    np.testing.assert_allclose(tracker.optimistic(), head.optimistic(queries[:10]), rtol=RTOL)
    head.update(states[:25], rewards[:25])
    tracker.extend(queries[10:30])
    head.update(states[25:40], rewards[25:40])
    head.update(states[40:], rewards[40:])  # two updates folded at once
    tracker.extend(queries[30:])
    assert tracker.n_states == 40
    np.testing.assert_allclose(tracker.estimate(), head.estimate(queries), rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(tracker.bonus(), head.bonus(queries), rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(tracker.optimistic(), head.optimistic(queries), rtol=RTOL)


@pytest.mark.parametrize("make_head", all_beyond_heads())
@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_copies_answer_and_learn_as_the_original(make_head, how):
    """A pickled or deep-copied head (as TRLSD keeps one per task) gives the same R~ now and after updates."""
    head = make_head()
    states, rewards = line_samples(30, seed=9)
    head.update(states[:20], rewards[:20])
    queries = np.linspace(0, 1, 5).reshape(-1, 1)
    head.snapshot()
    clone = pickle.loads(pickle.dumps(head)) if how == "pickle" else copy.deepcopy(head)
    assert type(clone) is type(head) and clone.n_samples == 20
    for twin in (head, clone):
        twin.update(states[20:], rewards[20:])
    np.testing.assert_array_equal(clone.optimistic(queries), head.optimistic(queries))
    np.testing.assert_array_equal(clone.uncertainty(queries), head.uncertainty(queries))


@pytest.mark.parametrize(
    ("build", "argument"),
    [
        pytest.param(lambda: RidgePosteriorRewardHead("phi"), "features", id="features-not-callable"),
        pytest.param(lambda: RidgePosteriorRewardHead(LINE, ridge=0.0), "ridge", id="ridge-0"),
        pytest.param(lambda: RidgePosteriorRewardHead(LINE, kappa=-1.0), "kappa", id="kappa-negative"),
        pytest.param(lambda: ThompsonRidgeRewardHead(LINE, seed=-1), "seed", id="seed-negative"),
        pytest.param(lambda: ThompsonRidgeRewardHead(LINE, seed=1.5), "seed", id="seed-float"),
        pytest.param(
            lambda: ThompsonRidgeRewardHead(LINE, kappa_scale="max"), "kappa_scale", id="kappa-scale"
        ),
        pytest.param(lambda: BernsteinRewardHead(sigma=0.0), "sigma", id="sigma-0"),
        pytest.param(lambda: BernsteinRewardHead(sigma=np.inf), "sigma", id="sigma-inf"),
        pytest.param(lambda: BernsteinRewardHead(reward_range=-1.0), "reward_range", id="range-negative"),
        pytest.param(lambda: BernsteinRewardHead(w_floor=0.0), "w_floor", id="w_floor-0"),
        pytest.param(
            lambda: RidgePosteriorRewardHead(LINE).refit_due(None, np.zeros(1), update_ratio=1.0),
            "update_ratio",
            id="update_ratio-1",
        ),
        pytest.param(lambda: make_reward_head("thompson"), "features", id="named-without-features"),
        pytest.param(
            lambda: make_reward_head("bernstein", similarity="features"), "similarity", id="bernstein-eq-7"
        ),
    ],
)
def test_bad_arguments_are_refused_by_name(build, argument):
    with pytest.raises(ValueError, match=argument):
        build()


def test_make_reward_head_builds_the_new_heads_by_name():
    """The registered names give the classes, with kappa, sigma and the head's own keyword arguments."""
    posterior = make_reward_head("ridge_posterior", features=LINE, kappa=0.3, ridge=2.0)
    thompson = make_reward_head("thompson", features=LINE, kappa=0.3, seed=4)
    bernstein = make_reward_head("bernstein", kappa=0.3, sigma=0.05, reward_range=3.0)
    assert type(posterior) is RidgePosteriorRewardHead and (posterior.kappa, posterior.ridge) == (0.3, 2.0)
    assert type(thompson) is ThompsonRidgeRewardHead and (thompson.kappa, thompson.seed) == (0.3, 4)
    assert type(bernstein) is BernsteinRewardHead
    assert (bernstein.kappa, bernstein.sigma, bernstein.reward_range) == (0.3, 0.05, 3.0)


@pytest.mark.parametrize(
    "head",
    [
        pytest.param(RidgePosteriorRewardHead(MAZE_GRID), id="ridge_posterior"),
        pytest.param(ThompsonRidgeRewardHead(MAZE_GRID, seed=0), id="thompson"),
        pytest.param(BernsteinRewardHead(sigma=0.2), id="bernstein"),
    ],
)
def test_trlsd_learns_with_the_head(head):
    """
    TRLSD takes the head as an instance, copies it for its task and feeds it every step; beyond the first fit
    (at the first step, whatever the head) the section-3 trigger refits on the head's snapshots.
    """
    model = TRLSD("LinearPolicy", gym.make(MAZE_ID, task=0), reward_head=head, seed=0)
    model.learn(60)
    task_head = model.task_learner(0).head
    assert type(task_head) is type(head) and task_head is not head
    assert task_head.n_samples == 60 and head.n_samples == 0
    assert model.policy_updates[0] >= 2


# ------------------------------------------------------------------------------------------ by name in TRLSD
NAMED_HEADS = [
    # name, its own setting through reward_head_kwargs, the head's attribute that shows it, the class
    pytest.param("ridge_posterior", {"ridge": 2.0}, "ridge", RidgePosteriorRewardHead, id="ridge_posterior"),
    pytest.param("thompson", {"ridge": 2.0}, "ridge", ThompsonRidgeRewardHead, id="thompson"),
    pytest.param("bernstein", {"reward_range": 3.0}, "reward_range", BernsteinRewardHead, id="bernstein"),
]


@pytest.mark.parametrize(("name", "kwargs", "attribute", "head_class"), NAMED_HEADS)
def test_trlsd_builds_the_head_by_name_saves_and_loads_it(name, kwargs, attribute, head_class, tmp_path):
    """
    ``TRLSD(reward_head=name)`` builds the head with the model's kappa, its features (the linear-posterior
    heads) or its sigma in state units (Bernstein: 0.04 of the box is the paper's 0.2), and its own setting
    from ``reward_head_kwargs``; a saved model loads with the same head, which answers and learns as before.
    """
    model = TRLSD(
        "LinearPolicy",
        gym.make(MAZE_ID, task=3),
        reward_head=name,
        kappa=0.3,
        sigma=0.04,
        reward_head_kwargs=kwargs,
        source_transitions=400,
        seed=2,
    )
    model.learn(50)
    head = model.task_learner(3).head
    assert type(head) is head_class and head.kappa == 0.3 and head.n_samples == 50
    assert getattr(head, attribute) == next(iter(kwargs.values()))
    if name == "bernstein":
        assert head.sigma == pytest.approx(0.2)
    else:
        assert head.features is model.features
    assert model.policy_updates[3] >= 2

    model.save(tmp_path / "model")
    loaded = TRLSD.load(tmp_path / "model", env=gym.make(MAZE_ID, task=3))
    assert loaded.config.reward_head == name and type(loaded.task_learner(3).head) is head_class
    states = np.random.default_rng(0).uniform(0, 5, size=(200, 2))
    new_states, new_rewards = np.random.default_rng(1).uniform(0, 5, size=(30, 2)), np.ones(30)
    for twin in (model, loaded):
        np.testing.assert_array_equal(twin.task_learner(3).head.optimistic(states), head.optimistic(states))
    for twin in (model, loaded):
        twin.task_learner(3).head.update(new_states, new_rewards)
    np.testing.assert_array_equal(
        loaded.task_learner(3).head.optimistic(states), model.task_learner(3).head.optimistic(states)
    )
    np.testing.assert_array_equal(
        loaded.task_learner(3).head.uncertainty(states), model.task_learner(3).head.uncertainty(states)
    )


def test_named_thompson_heads_draw_per_seed_and_task_reproducibly():
    """Each task (and each seed) draws its own normals; the same seed gives the same draws again."""

    def head_seeds(seed):
        model = TRLSD("LinearPolicy", gym.make(MAZE_ID, tasks="all"), reward_head="thompson", seed=seed)
        return [model.task_learner(task).head.seed for task in (0, 1)]

    assert head_seeds(5) == head_seeds(5)
    assert len({*head_seeds(5), *head_seeds(6)}) == 4
    unseeded = TRLSD("LinearPolicy", gym.make(MAZE_ID), reward_head="thompson")
    assert unseeded.task_learner(0).head.seed is None  # no seed: fresh entropy, as the head itself takes it
    given = TRLSD("LinearPolicy", gym.make(MAZE_ID), reward_head="thompson", reward_head_kwargs={"seed": 7})
    assert given.task_learner(0).head.seed == 7


def test_trlsd_refuses_bernstein_with_the_feature_similarity():
    with pytest.raises(ValueError, match="similarity must be 'state'"):
        TRLSD("LinearPolicy", gym.make(MAZE_ID), reward_head="bernstein", similarity="features")


def test_bernstein_widths_per_dimension_are_one_width_on_rescaled_states():
    """Eq. 6 of widths (0.1, 0.4) is eq. 6 of width 0.1 on states whose second coordinate is divided by 4."""
    rng = np.random.default_rng(3)
    states, rewards, queries = rng.uniform(0, 1, (40, 2)), rng.normal(size=40), rng.uniform(0, 1, (9, 2))
    scale = np.array([1.0, 0.25])
    per_dimension = fed(BernsteinRewardHead(kappa=0.4, sigma=(0.1, 0.4)), states, rewards)
    rescaled = fed(BernsteinRewardHead(kappa=0.4, sigma=0.1), states * scale, rewards)
    np.testing.assert_allclose(per_dimension.optimistic(queries), rescaled.optimistic(queries * scale), RTOL)
    tracker = per_dimension.tracker(queries)
    np.testing.assert_allclose(tracker.optimistic(), per_dimension.optimistic(queries), RTOL)
