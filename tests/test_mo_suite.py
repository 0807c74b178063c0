"""The MO-Gymnasium suite (``experiments/mo_suite``): families, their envs, one small cell end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("mo_gymnasium")

from sb3_trlsd_lab.benchmarks.mo_suite.families import (
    FAMILIES,
    available,
    collect_source,
    family_weights,
    make_env,
    reward_bound,
    weight_split,
)
from sb3_trlsd_lab.benchmarks.mo_suite.peers import METHODS, SETTABLE, run_method
from sb3_trlsd_lab.benchmarks.mo_suite.sources import (
    offline_parameters,
    source_of,
    source_updates,
    trained_source,
)
from sb3_trlsd_lab.benchmarks.mo_suite.suite import (
    family_scale,
    fraction_interval,
    goal_table,
    paired_gain,
    protocol_table,
    reference_fraction,
    run_suite,
)
from sb3_trlsd_lab.cli import main

GRID_FAMILIES = ["deep-sea-treasure-v0", "resource-gathering-v0", "four-room-v0"]


@pytest.mark.parametrize("name", list(FAMILIES))
def test_weight_splits_are_disjoint_seeded_and_on_the_simplex(name):
    """Source, tuning and evaluation weights share no vector (a target seen as a source would leak), are
    the same at every call (runs could not be compared otherwise) and are convex combinations."""
    family = FAMILIES[name]
    assert available(family), f"{name} needs {family.requires}: the dev extra installs it"
    split = weight_split(family)
    rows = {tuple(np.round(w, 12)) for part in (split.source, split.tuning, split.evaluation) for w in part}
    assert len(rows) == family.n_tasks
    assert (
        len(split.evaluation) == family.n_evaluation_weights and len(split.source) == family.n_source_weights
    )
    np.testing.assert_array_equal(family_weights(family), family_weights(family))
    np.testing.assert_allclose(family_weights(family).sum(axis=1), 1.0)
    assert np.all(family_weights(family) >= 0)
    tasks = [set(family.tasks_of(s).tolist()) for s in ("source", "tuning", "evaluation")]
    assert set.union(*tasks) == set(range(family.n_tasks)) and sum(map(len, tasks)) == family.n_tasks


@pytest.mark.parametrize("name", ["deep-sea-treasure-v0", "minecart-v0", "mo-mountaincar-v0", "four-room-v0"])
def test_scalar_reward_is_the_task_weights_times_the_reward_vector(name):
    """The env pays w_task . r_vec, with the vector in info: a mix-up of tasks or weights would show, as
    would a reward taken from another objective; the state is a vector in the declared Box's shape, of
    integers where the env's Box is (deep-sea treasure's and four-room's cells), else of float64."""
    family = FAMILIES[name]
    task = int(family.tasks_of("evaluation")[3])
    env = make_env(family, task)
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    vectors = []
    for _ in range(200):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(env.action_space.n)))
        expected = np.int32 if name in ("deep-sea-treasure-v0", "four-room-v0") else np.float64
        assert obs["task"] == task and obs["state"].dtype == expected
        assert env.observation_space["state"].contains(obs["state"])
        assert obs["state"].shape == env.observation_space["state"].shape
        assert reward == pytest.approx(float(family_weights(family)[task] @ info["vector_reward"]))
        vectors.append(info["vector_reward"])
        if terminated or truncated:
            obs, _ = env.reset()
    assert np.any(np.asarray(vectors) != 0)


@pytest.mark.parametrize("name", GRID_FAMILIES)
def test_family_bounds_hold_every_source_state(name):
    """The state bounds given to TRLSD contain the states the envs really take (narrower bounds would put
    states outside the features' box)."""
    family = FAMILIES[name]
    data = collect_source(family, 3_000, seed=1).transitions
    low, high = (np.asarray(b) for b in family.state_bounds)
    assert np.all(data.states >= low) and np.all(data.states <= high)


def test_source_set_is_split_over_the_source_weights_with_their_rewards():
    """Each source weight collects its share, rewards scalarised by its own weights, the vector kept; the
    same seed gives the same set (runs would not be reproducible otherwise)."""
    family = FAMILIES["deep-sea-treasure-v0"]
    source = collect_source(family, 1_000, seed=3)
    data = source.transitions
    assert len(data) == 1_000 and source.vector_rewards.shape == (1_000, 2)
    assert set(np.unique(data.tasks).tolist()) == set(family.tasks_of("source").tolist())
    weights = family_weights(family)[data.tasks]
    np.testing.assert_allclose(data.rewards, np.sum(weights * source.vector_rewards, axis=1))
    again = collect_source(family, 1_000, seed=3)
    np.testing.assert_array_equal(data.states, again.transitions.states)
    # every share ends with a reset, so no transition bootstraps into the next share's first state
    assert data.truncations[np.flatnonzero(np.diff(data.tasks))].all()


def test_reward_bound_is_the_largest_scalarised_reward():
    """The cap of the relabelled rewards: w . r_vec at its best corner of the reward box."""
    family = FAMILIES["deep-sea-treasure-v0"]
    env = make_env(family, 0)
    w = np.array([0.25, 0.75])
    assert reward_bound(env.reward_space, w) == pytest.approx(0.25 * 23.7 - 0.75, rel=1e-6)


@pytest.mark.parametrize("method", list(METHODS))
def test_every_method_runs_its_budget_on_the_targets_rewards(method):
    """Each method makes exactly the online budget's steps and is scored on the target's scalar rewards
    (bounded by the reward box), from a small source set."""
    family = FAMILIES["deep-sea-treasure-v0"]
    task = int(family.tasks_of("evaluation")[0])
    source = collect_source(family, 500, seed=0)
    result = run_method(method, family, task, seed=0, source=source, n_online=60)
    env = make_env(family, task)
    assert result.rewards.shape == (60,)
    assert np.all(result.rewards <= reward_bound(env.reward_space, family_weights(family)[task]) + 1e-9)
    assert result.seconds >= result.online_seconds > 0


def small_cell(family: str, out) -> int:
    """Two methods, two runs of a family through the command line, into ``out``."""
    return main(
        [
            "benchmark-suite",
            family,
            "--runs",
            "2",
            "--workers",
            "1",
            "--methods",
            "random",
            "trlsd",
            "--source",
            "500",
            "--online",
            "60",
            "--out",
            str(out),
            "--no-cache",
        ]
    )


def test_a_small_suite_cell_writes_its_csv_json_and_png(tmp_path):
    """One family, two methods, two runs through the command line: the CSV has a row per run, the JSON the
    aggregates with an interval around the mean, and the PNG is written; the tables in OUT gather every
    family run there, this command's and an earlier one's, in the suite's order."""
    assert small_cell("mo-mountaincar-v0", tmp_path) == 0
    assert small_cell("deep-sea-treasure-v0", tmp_path) == 0
    name = tmp_path / "mo_suite_deep-sea-treasure-v0"
    rows = name.with_suffix(".csv").read_text().strip().splitlines()
    assert len(rows) == 1 + 2 * 2 and rows[0].startswith("method,run,task")
    data = json.loads(name.with_suffix(".json").read_text())
    assert set(data["results"]) == {"random", "trlsd"}
    for entry in data["results"].values():
        low, high = entry["ci95"]
        assert low <= entry["score"]["mean"] <= high and entry["runs"] == 2
    assert data["parameters"]["online_transitions"] == 60
    assert name.with_suffix(".png").stat().st_size > 0
    table = (tmp_path / "mo_suite_table.md").read_text()
    assert table.index("| deep-sea-treasure-v0 | TRLSD") < table.index("| mo-mountaincar-v0 | TRLSD")
    assert table.count("| deep-sea-treasure-v0 | ") == 2  # two methods (a goal row needs DQN's runs)


def test_run_suite_refuses_unknown_methods(tmp_path):
    """A misspelt method is named before anything runs."""
    with pytest.raises(ValueError, match="methods must be among"):
        run_suite("deep-sea-treasure-v0", tmp_path, runs=1, methods=["trlsd", "dqn2"])


def test_settings_reach_trlsd_and_no_other_method():
    """A candidate's settings are TRLSD's keyword arguments, for each TRLSD method (either policy, without or
    with the true reward); given to another method they are refused."""
    family = FAMILIES["deep-sea-treasure-v0"]
    task = int(family.tasks_of("tuning")[0])
    source = collect_source(family, 300, seed=0)
    assert set(SETTABLE) == {"trlsd", "trlsd-reward-given", "trlsd-mlp", "trlsd-mlp-reward-given"}
    for method in SETTABLE:
        with pytest.raises(ValueError, match="kappa"):
            run_method(method, family, task, seed=0, source=source, n_online=5, settings={"kappa": -1.0})
    with pytest.raises(ValueError, match="settings are TRLSD's"):
        run_method("dqn", family, task, seed=0, source=source, n_online=5, settings={"kappa": 1.0})


@pytest.mark.parametrize("method", ["trlsd-mlp", "trlsd-mlp-reward-given"])
def test_the_mlp_methods_run_trlsd_with_its_network_q(method):
    """The MLP methods are TRLSD with ``MlpPolicy``: a network's layers are theirs to set, and the linear
    methods, whose Q has none, refuse them."""
    family = FAMILIES["deep-sea-treasure-v0"]
    task = int(family.tasks_of("tuning")[0])
    source = collect_source(family, 300, seed=0)
    layers = {"policy_kwargs": {"net_arch": [8]}}
    result = run_method(method, family, task, seed=0, source=source, n_online=5, settings=layers)
    assert result.rewards.shape == (5,) and result.updates >= 1
    with pytest.raises(TypeError, match="net_arch"):
        linear = method.replace("-mlp", "")
        run_method(linear, family, task, seed=0, source=source, n_online=5, settings=layers)


def test_the_goal_table_says_which_goal_holds_from_the_paired_differences():
    """Above random and ahead of DQN mean by more than 2 paired standard errors; the reference at 70%."""
    rows = {
        "trlsd": [{"score": s} for s in (1.0, 1.2, 1.1, 1.3)],
        "dqn": [{"score": s} for s in (0.9, 1.2, 1.0, 1.3)],
        "random": [{"score": s} for s in (0.0, 0.1, 0.0, 0.1)],
    }
    gain, versus = paired_gain(rows["trlsd"], rows["random"]), paired_gain(rows["trlsd"], rows["dqn"])
    assert gain["mean"] == pytest.approx(1.1) and versus["mean"] == pytest.approx(0.05)
    data = {
        "parameters": {"family": "f", "methods": {"trlsd": "TRLSD"}},
        "results": {"trlsd": {"gain_over_random": gain}},
        "goals": {"trlsd": {"minus_dqn": versus, "fraction_of_reward_given": 0.65}},
    }
    row = goal_table([data]).splitlines()[-1]
    # 1.1 ± 0.041 above random; 0.05 ± 0.029 ahead of DQN is within 2 SE; 65% is short of 70%.
    cells = ["TRLSD", "+1.100 ± 0.041", "yes", "+0.050 ± 0.029", "**no**", "65%", "**no** |"]
    assert row.split(" | ")[1:] == cells
    data["goals"]["trlsd"]["fraction_ci95"] = [0.52, 0.81]
    assert goal_table([data]).splitlines()[-1].split(" | ")[6] == "65% [52%, 81%]"


def test_the_fraction_of_the_reward_given_level_comes_with_its_paired_interval():
    """The point is (TRLSD - random) / (reference - random) of the means; the runs are resampled whole."""
    scores = {
        "trlsd": [0.5, 0.9, 0.2, 0.6, 0.4],
        "trlsd-reward-given": [1.0, 1.1, 0.3, 0.9, 0.6],
        "random": [0.1, 0.2, 0.0, 0.1, 0.0],
    }
    by_method = {name: [{"score": s} for s in values] for name, values in scores.items()}
    results = {name: {"score": {"mean": float(np.mean(values))}} for name, values in scores.items()}
    fraction = reference_fraction(results, "trlsd")
    assert fraction == pytest.approx((0.52 - 0.08) / (0.78 - 0.08))
    low, high = fraction_interval(by_method, "trlsd")
    assert low < fraction < high <= 1.5
    assert fraction_interval({"trlsd": by_method["trlsd"]}, "trlsd") is None


def test_family_scale_is_the_range_of_the_means_or_twice_their_median_error():
    """A family where the candidates tie within the noise is scaled by the noise, not by a tiny range."""
    spread, tied = np.array([0.1, 0.5, 0.3]), np.array([0.001, 0.002, 0.0])
    errors = np.array([0.01, 0.02, 0.03])
    assert family_scale(spread, errors) == pytest.approx(0.4)
    assert family_scale(tied, errors) == pytest.approx(0.04)
    assert family_scale(np.zeros(3), np.zeros(3)) == 1.0


def test_the_trained_source_is_the_buffer_of_a_dqn_trained_on_the_source_weights():
    """Under the trained protocol a run's source is its DQN's replay buffer: one row per step it took, every
    source weight drawn, each reward the weights of its row's task times the reward vector kept beside it,
    and the DQN's parameters for the fine-tuned DQN; the same seed gives the same rows."""
    family = FAMILIES["deep-sea-treasure-v0"]
    source = trained_source(family, 400, seed=2)
    data = source.transitions
    assert len(data) == 400 and source.vector_rewards.shape == (400, 2)
    assert set(np.unique(data.tasks).tolist()) <= set(family.tasks_of("source").tolist())
    assert len(np.unique(data.tasks)) > 1
    scalar = np.sum(family_weights(family)[data.tasks] * source.vector_rewards, axis=1)
    np.testing.assert_allclose(data.rewards, scalar, rtol=1e-5, atol=1e-5)
    assert data.terminations.any() and source.dqn_parameters is not None
    assert {"q_net.q_net.0.weight", "q_net_target.q_net.0.weight"} <= set(source.dqn_parameters)
    np.testing.assert_array_equal(trained_source(family, 400, seed=2).transitions.states, data.states)
    with pytest.raises(ValueError, match="source_policy must be one of"):
        source_of(family, "expert", 400, seed=2)


def test_the_random_protocols_fine_tuned_dqn_starts_from_an_offline_dqn_on_the_random_rows():
    """Under the random protocol there is no source DQN: one is trained offline on the random rows, its
    target network updated as DQN's is (so it equals the online one after a last update, at a multiple of
    the interval); it moved from where a fresh DQN starts."""
    family = FAMILIES["deep-sea-treasure-v0"]
    source = collect_source(family, 350, seed=0)
    assert source_updates(350) == 250 and source.dqn_parameters is None
    parameters = offline_parameters(family, source, seed=0)
    fresh = offline_parameters(family, collect_source(family, 100, seed=0), seed=0)  # no gradient step
    np.testing.assert_array_equal(
        parameters["q_net_target.q_net.0.weight"], parameters["q_net.q_net.0.weight"]
    )
    assert not np.allclose(parameters["q_net.q_net.0.weight"], fresh["q_net.q_net.0.weight"])


def test_a_small_trained_protocol_cell_shares_the_runs_without_a_source(tmp_path):
    """Both protocols through the command line: the trained protocol writes its own files and the table of
    the two side by side, and its methods without a source (the random policy here) are the random
    protocol's runs, kept once: 2 runs x (2 methods of the random protocol + 1 trained-source job)."""
    argv = ["benchmark-suite", "deep-sea-treasure-v0", "--runs", "2", "--workers", "1"]
    argv += ["--methods", "random", "trlsd", "--source", "300", "--online", "40"]
    argv += [
        "--source-policy",
        "random",
        "trained",
        "--out",
        str(tmp_path),
        "--cache",
        str(tmp_path / "runs"),
    ]
    assert main(argv) == 0
    trained = json.loads((tmp_path / "mo_suite_trained_deep-sea-treasure-v0.json").read_text())
    plain = json.loads((tmp_path / "mo_suite_deep-sea-treasure-v0.json").read_text())
    assert (
        trained["parameters"]["source_policy"] == "trained"
        and plain["parameters"]["source_policy"] == "random"
    )
    assert trained["results"]["random"] == plain["results"]["random"]
    assert len(list((tmp_path / "runs").glob("*.npz"))) == 6
    table = (tmp_path / "mo_suite_protocols.md").read_text().splitlines()
    assert table[0].startswith("| family | method | random source: score")
    assert [line.split(" | ")[1] for line in table[2:]] == ["TRLSD (defaults)", "random policy"]


def test_the_protocol_table_puts_each_methods_two_sources_side_by_side():
    """One row per family and method, the random source's cells then the trained one's, empty where a
    protocol did not run the method."""

    def summary(policy, scores):
        results = {
            method: {"score": {"mean": mean, "se": 0.01}, "gain_over_random": {"mean": mean, "se": 0.02}}
            for method, mean in scores.items()
        }
        return {"parameters": {"family": "f", "source_policy": policy}, "results": results}

    datas = [summary("random", {"trlsd": 0.5, "dqn": 0.1}), summary("trained", {"trlsd": 0.25})]
    rows = protocol_table(datas).splitlines()[2:]
    assert (
        rows[0]
        == "| f | TRLSD (defaults) | 0.500 ± 0.010 | +0.500 ± 0.020 | 0.250 ± 0.010 | +0.250 ± 0.020 |"
    )
    assert rows[1] == "| f | DQN (online only) | 0.100 ± 0.010 | +0.100 ± 0.020 |  |  |"
    assert len(rows) == 2
