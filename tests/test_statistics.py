"""
The aggregates of ``sb3_trlsd_lab.stats.statistics`` and the intervals of ``bootstrap`` against rliable's
definitions: closed forms and hand counts, the coverage of the stratified bootstrap, and the tables and
figure built on them.
"""

import numpy as np
import pytest
import scipy.stats
from matplotlib.image import imread

from sb3_trlsd_lab.paper.figures import write_improvement_figure
from sb3_trlsd_lab.paper.reporting import intervals_table, window_intervals, window_means
from sb3_trlsd_lab.stats import bootstrap
from sb3_trlsd_lab.stats.bootstrap import (
    aggregate_intervals,
    independent_bootstrap_ci,
    interval_cell,
    paired_bootstrap_ci,
    probability_of_improvement_ci,
    stratified_bootstrap_ci,
)
from sb3_trlsd_lab.stats.statistics import (
    aggregate_mean,
    aggregate_median,
    interquartile_mean,
    mean_ratio,
    optimality_gap,
    probability_of_improvement,
    scores_by_task,
)


@pytest.mark.parametrize("shape", [(4, 2), (5, 2), (7, 1)], ids=["8 scores", "10 scores", "7 scores"])
def test_iqm_is_the_mean_of_the_middle_half_of_all_runs_and_tasks(shape):
    """rliable's IQM trims int(n / 4) scores at each end of all runs x tasks together, not task by task."""
    scores = np.random.default_rng(1).exponential(size=shape) * 10
    ordered = np.sort(scores.ravel())
    cut = ordered.size // 4
    by_hand = ordered[cut : ordered.size - cut].mean()
    assert interquartile_mean(scores) == pytest.approx(by_hand)
    assert interquartile_mean(scores) == pytest.approx(scipy.stats.trim_mean(scores, 0.25, axis=None))
    batch = np.stack([scores, scores + 1.0, 2 * scores])
    np.testing.assert_allclose(interquartile_mean(batch), [by_hand, by_hand + 1.0, 2 * by_hand])


def test_aggregates_follow_their_closed_forms():
    """Mean and median are over tasks of the task means; the gap counts scores above gamma as gamma."""
    scores = np.array([[0.0, 1.0, 4.0], [2.0, 3.0, 0.5]])  # task means 1, 2, 2.25
    assert aggregate_mean(scores) == pytest.approx((1 + 2 + 2.25) / 3)
    assert aggregate_median(scores) == pytest.approx(2.0)
    assert optimality_gap(scores) == pytest.approx(1 - (0 + 1 + 1 + 1 + 1 + 0.5) / 6)
    assert optimality_gap(scores, gamma=3.0) == pytest.approx(3 - (0 + 1 + 3 + 2 + 3 + 0.5) / 6)
    assert aggregate_mean(np.array([1.0, 2.0, 6.0])) == pytest.approx(3.0)  # 1-D: one task


def brute_force_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) by counting every pair of runs of every task, a tie as one half."""
    per_task = []
    for task in range(x.shape[1]):
        wins = sum(float(a > b) + 0.5 * float(a == b) for a in x[:, task] for b in y[:, task])
        per_task.append(wins / (len(x) * len(y)))
    return float(np.mean(per_task))


@pytest.mark.parametrize("n_x, n_y", [(5, 5), (4, 9), (12, 3)])
def test_probability_of_improvement_counts_every_pair_with_ties_as_half(n_x, n_y):
    """Integer scores make ties common: counting them 0 or 1 instead of 0.5 would move P(X > Y)."""
    rng = np.random.default_rng(n_x * n_y)
    x, y = rng.integers(0, 4, size=(n_x, 3)).astype(float), rng.integers(0, 4, size=(n_y, 3)).astype(float)
    assert probability_of_improvement(x, y) == pytest.approx(brute_force_improvement(x, y))
    assert probability_of_improvement(x, y) + probability_of_improvement(y, x) == pytest.approx(1.0)
    u_statistics = [scipy.stats.mannwhitneyu(x[:, t], y[:, t]).statistic for t in range(3)]
    assert probability_of_improvement(x, y) == pytest.approx(np.mean(u_statistics) / (n_x * n_y))
    assert probability_of_improvement(x, x) == pytest.approx(0.5)  # rliable's equal columns


def test_probability_of_improvement_is_batched_over_leading_axes():
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=(3, 6, 2)), rng.normal(size=(3, 4, 2))
    expected = [brute_force_improvement(x[i], y[i]) for i in range(3)]
    np.testing.assert_allclose(probability_of_improvement(x, y), expected)


def test_bootstrap_interval_covers_the_true_mean_at_about_its_rate():
    """
    200 seeded samples of 30 runs from N(0, 1): the 90 % interval should cover 0 about 90 % of the time
    (binomial sd 2.1 points; the percentile interval under-covers slightly at 30 runs). An interval of
    the wrong width (half: ~60 %, double: ~100 %) or centred elsewhere falls outside [83 %, 97 %].
    """
    rng = np.random.default_rng(2021)
    covered = 0
    for sample in range(200):
        scores = rng.normal(size=30)
        _, low, high = stratified_bootstrap_ci(scores, aggregate_mean, reps=400, confidence=0.9, seed=sample)
        covered += low <= 0.0 <= high
    assert 0.83 <= covered / 200 <= 0.97


def test_interval_is_the_percentile_interval_of_the_resamples():
    """Each resample draws every cell's run within its column; the ends are np.percentile's (arch's)."""
    scores = np.random.default_rng(3).normal(size=(8, 3))
    reps, seed = 300, 11
    point, low, high = stratified_bootstrap_ci(
        scores, interquartile_mean, reps=reps, confidence=0.8, seed=seed
    )
    rows = np.random.default_rng(seed).integers(0, 8, size=(reps, 8, 3))
    estimates = [
        scipy.stats.trim_mean(
            np.array([[scores[rows[r, i, t], t] for t in range(3)] for i in range(8)]), 0.25, None
        )
        for r in range(reps)
    ]
    assert point == pytest.approx(scipy.stats.trim_mean(scores, 0.25, axis=None))
    assert (low, high) == pytest.approx(tuple(np.percentile(estimates, [10, 90])))


def test_stratified_resamples_keep_each_task_in_its_column():
    """
    Task t's scores are 100 t + run: a resample that mixed rows across tasks would put a score of one task
    in another's column. Two equal columns must still be resampled cell by cell (rliable draws a run for
    every cell), not row by row.
    """
    scores = 100.0 * np.arange(4) + np.arange(10)[:, None]
    scores[:, 3] = scores[:, 2]
    batches = []

    def recording_mean(batch: np.ndarray) -> np.ndarray:
        batches.append(batch)
        return aggregate_mean(batch)

    stratified_bootstrap_ci(scores, recording_mean, reps=200, seed=0)
    resamples = batches[0]
    assert resamples.shape == (200, 10, 4)
    for task in range(4):
        assert np.isin(resamples[..., task], scores[:, task]).all()
    assert not np.array_equal(resamples[..., 2], resamples[..., 3])
    assert len(np.unique(resamples[..., 0])) == 10  # every run gets drawn


def test_bootstrap_draws_every_resample_once_in_batches(monkeypatch):
    """2,000 resamples of 500 runs in one call of the statistic; in chunks when they would not fit."""
    sizes = []

    def counting_mean(batch: np.ndarray) -> np.ndarray:
        sizes.append(batch.shape[:-2])
        return aggregate_mean(batch)

    scores = np.random.default_rng(4).normal(size=500)
    stratified_bootstrap_ci(scores, counting_mean, reps=2_000)
    assert sizes == [(2_000,), ()]  # the resamples, then the point estimate
    sizes.clear()
    monkeypatch.setattr(bootstrap, "CHUNK_ELEMENTS", 500 * 300)
    stratified_bootstrap_ci(scores, counting_mean, reps=2_000)
    assert sizes == [(300,)] * 6 + [(200,), ()]


def test_bootstrap_is_seeded():
    scores = np.random.default_rng(5).normal(size=(20, 2))
    first = stratified_bootstrap_ci(scores, interquartile_mean, reps=200, seed=7)
    assert stratified_bootstrap_ci(scores, interquartile_mean, reps=200, seed=7) == first
    assert stratified_bootstrap_ci(scores, interquartile_mean, reps=200, seed=8) != first


def test_probability_of_improvement_interval_resamples_x_and_y_independently():
    """
    With X equal to Y, resampling both with the same draws would give exactly 0.5 every time (an interval
    of width 0); rliable resamples them independently, so the interval straddles 0.5.
    """
    scores = np.random.default_rng(6).normal(size=(15, 2))
    point, low, high = probability_of_improvement_ci(scores, scores, reps=500, seed=0)
    assert point == pytest.approx(0.5)
    assert low < 0.45 and high > 0.55
    better = scores + 3.0
    point, low, high = probability_of_improvement_ci(better, scores, reps=500, seed=0)
    assert 0.9 < low <= point <= high <= 1.0


def test_aggregate_intervals_and_cells():
    scores = np.random.default_rng(7).normal(size=(40, 1))
    intervals = aggregate_intervals(scores, ("IQM", "mean", "median", "optimality gap"), reps=300)
    assert list(intervals) == ["IQM", "mean", "median", "optimality gap"]
    assert intervals["mean"]["point"] == pytest.approx(scores.mean())
    for interval in intervals.values():
        assert interval["low"] <= interval["point"] <= interval["high"]
    assert interval_cell(0.7543, 0.70149, 0.8) == "0.754 [0.701, 0.800]"


def test_window_intervals_put_bootstrap_cells_next_to_mean_and_standard_error():
    """The mean ± se cell must stay results_table's; the intervals are of the runs' window averages."""
    values = np.random.default_rng(8).uniform(size=(12, 6))
    cells = window_intervals(values, [(0, 3), (3, 6)], reps=300)
    means = window_means(values, [(0, 3), (3, 6)])
    assert list(cells["[0, 3)"]) == ["mean ± se", "mean [95% CI]", "IQM [95% CI]"]
    assert cells["[3, 6)"]["mean ± se"] == f"{means['[3, 6)']['mean']:.3f} ± {means['[3, 6)']['se']:.3f}"
    iqm = scipy.stats.trim_mean(values[:, :3].mean(axis=1), 0.25)
    assert cells["[0, 3)"]["IQM [95% CI]"].startswith(f"{iqm:.3f} [")

    table = intervals_table({"a": values, "b": values[:6]}, [(0, 3), (3, 6)], reps=100).splitlines()
    assert table[0] == "| method | window | mean ± se | mean [95% CI] | IQM [95% CI] |"
    assert [line.split(" | ")[:2] for line in table[2:]] == [
        ["| a", "[0, 3)"],
        ["| a", "[3, 6)"],
        ["| b", "[0, 3)"],
        ["| b", "[3, 6)"],
    ]


def test_scores_by_task_make_one_column_per_task_when_the_tasks_are_balanced():
    """Run r of a figure is on task r % n: column t holds task t's runs in order; unbalanced: one stratum."""
    scores, tasks = np.arange(6.0), np.array([0, 1, 2, 0, 1, 2])
    np.testing.assert_array_equal(scores_by_task(scores, tasks), [[0, 1, 2], [3, 4, 5]])
    np.testing.assert_array_equal(scores_by_task(scores[:5], tasks[:5]), scores[:5])
    np.testing.assert_array_equal(scores_by_task(scores, np.zeros(6)), scores)
    with pytest.raises(ValueError, match="n_runs"):
        scores_by_task(scores, tasks[:4])


def test_mean_ratio_is_the_ratio_of_the_aggregate_means_resampled_on_each_side():
    """The point is mean(X) / mean(Y); the interval (X, Y resampled apart) covers it, narrower with runs."""
    rng = np.random.default_rng(4)
    x, y = rng.normal(0.6, 0.2, (40, 5)), rng.normal(0.75, 0.2, (20, 5))
    point, low, high = independent_bootstrap_ci(mean_ratio, [x, y], reps=500)
    assert point == pytest.approx(aggregate_mean(x) / aggregate_mean(y))
    assert low < point < high
    _, wide_low, wide_high = independent_bootstrap_ci(mean_ratio, [x[:8], y[:4]], reps=500)
    assert wide_high - wide_low > high - low
    # A zero level: no finite interval.
    _, zero_low, zero_high = independent_bootstrap_ci(mean_ratio, [x, np.zeros(4)], reps=20)
    assert not np.isfinite([zero_low, zero_high]).any()


def test_paired_resamples_keep_each_runs_scores_together():
    """
    Scores that move together run by run (a shared target's scale) give a paired difference a narrow
    interval, and the runs' share of a reference's gain an exact one when that share is the same in every run.
    """
    rng = np.random.default_rng(5)
    scale = rng.uniform(0.1, 10.0, 30)  # each run's reward scale
    floor, reference = 0.2 * scale, 1.2 * scale
    method = floor + 0.7 * (reference - floor)  # 70% of the reference's gain in every run

    def share(x, ref, low):
        return np.mean(x - low, axis=-1) / np.mean(ref - low, axis=-1)

    point, low, high = paired_bootstrap_ci(share, [method, reference, floor], reps=300)
    assert point == pytest.approx(0.7) and low == pytest.approx(0.7) and high == pytest.approx(0.7)
    # Resampled apart (each method's runs drawn on their own), the same scores give a wide interval.
    _, apart_low, apart_high = independent_bootstrap_ci(
        lambda x, ref, low: share(x[..., 0], ref[..., 0], low[..., 0]), [method, reference, floor], reps=300
    )
    assert apart_high - apart_low > 0.3
    with pytest.raises(ValueError, match="one length"):
        paired_bootstrap_ci(share, [method, reference[:5], floor])


def test_improvement_figure_writes_a_png(tmp_path):
    rng = np.random.default_rng(9)
    scores = {
        "optimistic": rng.normal(0.7, 0.2, 20),
        "greedy": rng.normal(0.5, 0.2, 20),
        "tabular": rng.normal(size=20),
    }
    pairs = [("optimistic", "greedy"), ("optimistic", "tabular")]
    intervals = write_improvement_figure(tmp_path / "improvement.png", scores, pairs, "P(X > Y)", reps=200)
    assert list(intervals) == pairs
    image = imread(tmp_path / "improvement.png")
    assert image.shape[0] > 100 and image.shape[1] > 300
    assert image[..., :3].std() > 0.05  # something was drawn


@pytest.mark.parametrize(
    "call, message",
    [
        pytest.param(lambda: interquartile_mean(np.empty((0, 3))), "at least one run", id="no runs"),
        pytest.param(lambda: aggregate_mean(np.array([1.0, np.nan])), "finite", id="NaN"),
        pytest.param(lambda: interquartile_mean(np.float64(1.0)), "scalar", id="scalar"),
        pytest.param(
            lambda: probability_of_improvement(np.ones((3, 2)), np.ones((3, 3))),
            "same tasks",
            id="tasks differ",
        ),
        pytest.param(
            lambda: probability_of_improvement_ci(np.ones((3, 2)), np.ones((4, 1))),
            "same tasks",
            id="tasks differ (interval)",
        ),
        pytest.param(
            lambda: stratified_bootstrap_ci(np.ones((2, 3, 4)), aggregate_mean), "one", id="a batch"
        ),
        pytest.param(
            lambda: stratified_bootstrap_ci(np.ones(5), aggregate_mean, confidence=1.0),
            "confidence",
            id="confidence 1",
        ),
        pytest.param(
            lambda: stratified_bootstrap_ci(np.ones(5), aggregate_mean, reps=0), "reps", id="no resamples"
        ),
        pytest.param(
            lambda: stratified_bootstrap_ci(np.ones(5), lambda batch: 0.0, reps=10),
            "statistic must map",
            id="scalar statistic",
        ),
        pytest.param(
            lambda: aggregate_intervals(np.ones(5), ("IQR",)),
            "aggregates must be among",
            id="unknown aggregate",
        ),
        pytest.param(
            lambda: bootstrap.improvement_intervals({"a": np.ones(3)}, [("a", "b")]),
            "does not have",
            id="unknown method",
        ),
    ],
)
def test_bad_input_raises_a_clear_value_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()
