"""
``reproduce beyond`` (``sb3_trlsd_lab.studies.beyond``) at tiny sizes: tuning seeds disjoint from the
evaluation's, the selection of the best tuning score, a JSON whose aggregates are those of the runs, the
files, and the options refused.
"""

import csv
import json

import numpy as np
import pytest
import scipy.stats
from matplotlib.image import imread

from sb3_trlsd_envs import CELL_NOISE_STDS
from sb3_trlsd_lab.cli import main
from sb3_trlsd_lab.execution import batches
from sb3_trlsd_lab.execution.runner import Method
from sb3_trlsd_lab.paper.reporting import mean_and_standard_error
from sb3_trlsd_lab.paper.reproduction import Reproduction
from sb3_trlsd_lab.registry import STUDIES, reproduce
from sb3_trlsd_lab.studies import beyond
from sb3_trlsd_lab.studies.beyond import (
    GRIDS,
    REFERENCE,
    TUNING_SEED_OFFSET,
    evaluation_seeds,
    select_configuration,
    selection_window,
    tuning_seeds,
)
from sb3_trlsd_lab.studies.beyond_report import best_against_goal, verdict
from sb3_trlsd_lab.studies.tuning import TUNING_BATCH_RUNS, tuning_source_sets
from tests.conftest import record_figure_titles

RUNS, TUNING_RUNS, MLP_RUNS, SEED = 4, 3, 1, 7
N_SOURCE, N_ONLINE = 300, 30
# Two configurations per method, so that selection and evaluation run every kind of head at little cost.
SMALL_GRIDS = {name: grid[:1] + grid[-1:] for name, grid in GRIDS.items()}


class Recorder:
    """``transfer_runs`` as the study calls it, each call's arguments and results kept."""

    def __init__(self, monkeypatch):
        self.calls = []
        self.transfer_runs = beyond.transfer_runs
        monkeypatch.setattr(beyond, "transfer_runs", self)

    def __call__(self, methods, tasks, runs, seed, workers, **kwargs):
        records = self.transfer_runs(methods, tasks, runs, seed, workers, **kwargs)
        self.calls.append(
            {"methods": methods, "runs": runs, "seed": seed, "kwargs": kwargs, "records": records}
        )
        return records


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """
    One tiny study (both mazes, the MLP on one run), its JSON, every ``transfer_runs`` call it made and the
    titles of the figures it drew.
    """
    monkeypatch = pytest.MonkeyPatch()
    recorder = Recorder(monkeypatch)
    titles = record_figure_titles(monkeypatch)
    out = tmp_path_factory.mktemp("beyond")
    try:
        data = beyond.reproduce(
            out,
            Reproduction(runs=RUNS, seed=SEED),
            tuning_runs=TUNING_RUNS,
            mlp_runs=MLP_RUNS,
            grids=SMALL_GRIDS,
            n_source=N_SOURCE,
            n_online=N_ONLINE,
        )
    finally:
        monkeypatch.undo()
    return out, data, recorder.calls, titles


def test_tuning_seeds_are_disjoint_from_the_evaluation_seeds(study):
    """
    Every tuning call runs on seed + TUNING_SEED_OFFSET and its own source sets, every evaluation call on the
    seed itself: the run seeds and source-set seeds of the two never meet, and the JSON records them.
    """
    _, data, calls, _ = study
    tuning = [call for call in calls if call["runs"] == TUNING_RUNS]
    evaluation = [call for call in calls if call["runs"] != TUNING_RUNS]
    assert len(tuning) == 2 and len(evaluation) == 4  # per maze: a tuning, a linear and an MLP evaluation
    assert {call["seed"] for call in tuning} == {SEED + TUNING_SEED_OFFSET}
    assert {call["seed"] for call in evaluation} == {SEED}
    assert {call["runs"] for call in evaluation} == {RUNS, MLP_RUNS}
    tuned, evaluated = tuning_seeds(SEED, TUNING_RUNS), evaluation_seeds(SEED, RUNS)
    assert tuned["runs"] == list(range(SEED + TUNING_SEED_OFFSET, SEED + TUNING_SEED_OFFSET + TUNING_RUNS))
    assert evaluated["runs"] == list(range(SEED, SEED + RUNS))
    assert set(tuned["runs"]).isdisjoint(evaluated["runs"])
    assert set(tuned["source_sets"]).isdisjoint(evaluated["source_sets"])
    assert set(evaluation_seeds(SEED, MLP_RUNS)["source_sets"]) <= set(evaluated["source_sets"])
    recorded = data["parameters"]["seeds"]
    assert recorded["tuning"]["source_sets"] == tuned["source_sets"]
    assert (recorded["evaluation"]["first_run"], recorded["evaluation"]["last_run"]) == (
        SEED,
        SEED + RUNS - 1,
    )
    # Every configuration of every method was tuned on the same runs; the evaluation ran the selections.
    for call in tuning:
        assert [method.label for method in call["methods"]] == [
            c.label for g in SMALL_GRIDS.values() for c in g
        ]
    mazes = [call["kwargs"]["env_kwargs"] for call in tuning]
    assert mazes == [{}, {"reward_noise_std": CELL_NOISE_STDS}]


def test_the_selection_is_the_best_tuning_score_of_each_method(study):
    """The selected configuration has the highest mean over the tuning runs of the last-500 reward."""
    _, data, calls, _ = study
    window = selection_window(N_ONLINE)
    for maze, call in zip(
        data["tuning"], [call for call in calls if call["runs"] == TUNING_RUNS], strict=True
    ):
        for name, tuned in data["tuning"][maze].items():
            scores = {
                c.label: np.mean([r.rewards[window[0] : window[1]].mean() for r in call["records"][c.label]])
                for c in SMALL_GRIDS[name]
            }
            assert tuned["scores"] == pytest.approx(scores)
            assert tuned["score"] == max(scores.values())
            assert tuned["selected"] == next(
                label for label, score in scores.items() if score == max(scores.values())
            )
            assert data["results"][f"{maze}, linear Q: {name}"]["configuration"] == tuned["selected"]


def test_select_configuration_takes_the_highest_score_and_the_first_among_equals():
    assert select_configuration({"a": 0.2, "b": 0.5, "c": 0.1}) == "b"
    assert select_configuration({"a": 0.5, "b": 0.5}) == "a"
    with pytest.raises(ValueError, match="at least one"):
        select_configuration({})


def test_the_known_reward_wins_a_tuning_against_no_transfer(tmp_path):
    """
    A case whose answer is known: the known reward fitted on a source set against no transfer at all. The
    known reward is second in grid order, so that a tie (or a selection by order) would pick the other.
    """
    grids = {
        REFERENCE: (Method("no transfer", transfer=False), Method("known", reward_head="known", kappa=0.0))
    }
    data = beyond.reproduce(
        tmp_path,
        Reproduction(runs=1, seed=0),
        tuning_runs=3,
        grids=grids,
        mazes={"paper maze": {}},
        n_source=5_000,
        n_online=60,
    )
    tuned = data["tuning"]["paper maze"][REFERENCE]
    assert tuned["selected"] == "known" and tuned["scores"]["known"] > tuned["scores"]["no transfer"] + 0.2


def test_both_figures_name_the_protocol(study):
    out, _, _, titles = study
    assert {path.name for path in out.glob("*.png")} == {"beyond.png", "beyond_improvement.png"}
    named = [" ".join(title.split()).endswith("(protocol: as-built)") for title in titles]
    assert named == [True, True], titles


def test_the_json_has_every_field_and_aggregates_the_records(study):
    """
    Every field of the summary is there, and its numbers are the runs': the mean and clustered standard
    error of the last-500 window, the IQM, the fraction of the known reward and P(X > eq. 9), by hand.
    """
    out, data, calls, _ = study
    on_disk = json.loads((out / "beyond.json").read_text())
    assert on_disk == json.loads(json.dumps(data))
    assert set(data) >= {"figure", "package_version", "seed", "wall_time_seconds", "parameters", "grids"}
    assert set(data) >= {"tuning", "results", "files"} and data["figure"] == "beyond" and data["seed"] == SEED
    parameters = data["parameters"]
    assert parameters["runs"] == RUNS and parameters["tuning_runs"] == TUNING_RUNS
    assert parameters["mlp_runs"] == MLP_RUNS and parameters["protocol"]["name"] == "as-built"
    assert parameters["selection"]["window"] == "[0, 30)" and parameters["reference"] == REFERENCE
    assert data["grids"] == {name: [c.parameters() for c in grid] for name, grid in SMALL_GRIDS.items()}
    assert list(data["tuning"]) == ["paper maze", "noise by cell"]
    expected_rows = [
        f"{maze}, {q}: {method}"
        for maze in ("paper maze", "noise by cell")
        for q, methods in (("linear Q", [*SMALL_GRIDS, "known reward"]), ("MLP Q", list(SMALL_GRIDS)))
        for method in methods
    ]
    assert list(data["results"]) == expected_rows
    for label, entry in data["results"].items():
        assert {
            "reward",
            "intervals",
            "fraction_of_known",
            "policy_updates",
            "seconds_per_run",
            "runs",
        } <= set(entry)
        assert entry["runs"] == (MLP_RUNS if "MLP" in label else RUNS)
        for window in ("[0, 3)", "[0, 30)"):
            assert set(entry["intervals"][window]) == {"IQM", "mean"}
        has_comparison = entry["method"] not in (REFERENCE, "known reward")
        assert ("p_improvement" in entry) == has_comparison

    # One aggregate by hand: eq. 9 with the linear Q on the paper's maze, against the known reward.
    linear = next(call for call in calls if call["runs"] == RUNS)
    eq9, known = linear["records"][REFERENCE], linear["records"]["known reward"]
    scores = np.array([record.rewards.mean() for record in eq9])  # the window is all 30 transitions
    source_sets = np.array([record.source_set for record in eq9])
    mean, se = mean_and_standard_error(scores, source_sets)
    entry = data["results"][f"paper maze, linear Q: {REFERENCE}"]
    assert entry["reward"]["[0, 30)"]["mean"] == pytest.approx(mean)
    assert entry["reward"]["[0, 30)"]["se"] == pytest.approx(se)
    assert se == pytest.approx(np.std(scores, ddof=1) / np.sqrt(RUNS))  # 4 runs, 4 source sets
    iqm = entry["intervals"]["[0, 30)"]["IQM"]
    assert iqm["point"] == pytest.approx(scipy.stats.trim_mean(scores, 0.25))
    assert iqm["low"] <= iqm["point"] <= iqm["high"]
    known_mean = np.mean([record.rewards.mean() for record in known])
    fraction = entry["fraction_of_known"]["point"]
    assert (fraction is None) if known_mean == 0 else fraction == pytest.approx(mean / known_mean)
    # P(OFUL > eq. 9): one run per task (tasks 0-3), so per task 1, 1/2 or 0, averaged.
    oful = np.array([record.rewards.mean() for record in linear["records"]["OFUL"]])
    by_hand = np.mean((oful > scores) + 0.5 * (oful == scores))
    assert data["results"]["paper maze, linear Q: OFUL"]["p_improvement"]["point"] == pytest.approx(by_hand)
    # Each curve's verdict is its intervals', and the goal names each maze's best curve.
    for entry in data["results"].values():
        assert entry["verdict"] == verdict(entry)
    for maze in ("paper maze", "noise by cell"):
        fractions = [
            entry["fraction_of_known"]["point"]
            for entry in data["results"].values()
            if entry["maze"] == maze and entry["method"] != "known reward"
        ]
        fractions = [fraction for fraction in fractions if fraction is not None]  # None: a zero known level
        assert (maze in data["goal"]) == bool(fractions)
        if fractions:
            assert data["goal"][maze]["fraction_of_known"]["point"] == max(fractions)
            assert data["results"][data["goal"][maze]["curve"]]["maze"] == maze


def _entry(method="OFUL", improvement=(0.5, 0.4, 0.6), fraction=(0.7, 0.65, 0.75)):
    """A curve's entry with the intervals ``verdict`` reads, as (point, low, high)."""
    as_json = dict(zip(("point", "low", "high"), fraction, strict=True))
    entry = {"method": method, "maze": "paper maze", "fraction_of_known": as_json}
    if improvement is not None:
        entry["p_improvement"] = dict(zip(("point", "low", "high"), improvement, strict=True))
    return entry


@pytest.mark.parametrize(
    ("entry", "expected"),
    [
        (_entry(), "no clear difference from eq. 9; misses the 80% goal by 10.0% of the known level"),
        (_entry(improvement=(0.7, 0.55, 0.8), fraction=(0.85, 0.8, 0.9)), "beats eq. 9; reaches the 80%"),
        (_entry(improvement=(0.3, 0.2, 0.45), fraction=(0.8, 0.7, 0.9)), "below eq. 9; the 80% goal within"),
        (_entry(method=REFERENCE, improvement=None, fraction=(0.9, 0.85, 0.95)), "reaches the 80% goal"),
        (_entry(method=REFERENCE, improvement=None, fraction=(None, None, None)), ""),
        (_entry(method="known reward", improvement=None, fraction=(1.0, 1.0, 1.0)), ""),
    ],
)
def test_a_verdict_reads_the_intervals_against_one_half_and_the_goal(entry, expected):
    assert verdict(entry).startswith(expected)


def test_the_best_curve_of_each_maze_against_the_goal():
    results = {
        "a": _entry(method="OFUL", fraction=(0.7, 0.6, 0.79)),
        "b": _entry(method="Thompson", fraction=(0.75, 0.7, 0.85)),
        "c": _entry(method="known reward", fraction=(1.0, 1.0, 1.0)),
        "d": {**_entry(method="OFUL", fraction=(0.9, 0.85, 0.95)), "maze": "noise by cell"},
    }
    best = best_against_goal(results)
    assert best["paper maze"]["curve"] == "b" and best["paper maze"]["reached"] is None
    assert best["paper maze"]["missed_by"] == pytest.approx(0.05)
    assert best["noise by cell"] == {
        "curve": "d",
        "fraction_of_known": {"point": 0.9, "low": 0.85, "high": 0.95},
        "goal": 0.8,
        "reached": True,
        "missed_by": pytest.approx(-0.1),
    }
    results["a"]["fraction_of_known"] = {"point": 0.75, "low": 0.7, "high": 0.79}
    assert best_against_goal(results)["paper maze"]["curve"] == "a"  # the first of equals
    results["b"]["fraction_of_known"] = {"point": 0.5, "low": 0.45, "high": 0.55}
    assert best_against_goal(results)["paper maze"] == {
        "curve": "a",
        "fraction_of_known": {"point": 0.75, "low": 0.7, "high": 0.79},
        "goal": 0.8,
        "reached": False,
        "missed_by": pytest.approx(0.05),
    }


def test_the_files_are_written(study):
    """beyond.csv (a row per transition and curve), beyond.png, beyond_improvement.png, beyond.json."""
    out, data, _, _ = study
    assert sorted(path.name for path in out.iterdir()) == [
        "beyond.csv",
        "beyond.json",
        "beyond.png",
        "beyond_improvement.png",
    ]
    assert sorted(data["files"]) == sorted(str(path) for path in out.iterdir())
    with open(out / "beyond.csv") as file:
        rows = list(csv.DictReader(file))
    assert set(rows[0]) == {"transition", "method", "mean", "se", "runs"}
    assert len(rows) == N_ONLINE * len(data["results"])
    assert {row["method"] for row in rows} == set(data["results"])
    for name in ("beyond.png", "beyond_improvement.png"):
        image = imread(out / name)
        assert image.ndim == 3 and min(image.shape[:2]) > 200 and image[..., :3].std() > 0.05
    assert "| paper maze, linear Q | eq. 9 |" in beyond.table(data)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"tuning_runs": 0}, "tuning_runs must be an integer >= 1"),
        ({"mlp_runs": -1}, "mlp_runs must be an integer >= 0"),
        ({"mlp_runs": 3}, "mlp_runs must be at most runs"),
        ({"tuning_runs": 2.5}, "tuning_runs must be an integer"),
        ({"grids": {"OFUL": GRIDS["OFUL"]}}, "'eq. 9'"),
        ({"grids": {REFERENCE: GRIDS[REFERENCE][:1] * 2}}, "each configuration its own way"),
        ({"grids": {REFERENCE: GRIDS[REFERENCE], "known reward": GRIDS["OFUL"]}}, "reference level"),
        ({"mazes": {}}, "at least one maze"),
        ({"mazes": ["paper-maze", "the moon"]}, "mazes must be among paper-maze, noise-by-cell"),
    ],
    ids=[
        "no-tuning-runs",
        "negative-mlp-runs",
        "more-mlp-than-runs",
        "fractional",
        "no-eq-9",
        "twice",
        "known",
        "no-maze",
        "unknown-maze",
    ],
)
def test_bad_options_are_refused_before_any_run(options, message, tmp_path, monkeypatch):
    def no_run(*args, **kwargs):
        raise AssertionError("a run started")

    monkeypatch.setattr(beyond, "transfer_runs", no_run)
    with pytest.raises(ValueError, match=message):
        beyond.reproduce(tmp_path, Reproduction(runs=2), **options)
    with pytest.raises(ValueError, match="runs must be at most"):
        beyond.check_sizes(TUNING_SEED_OFFSET + 1, 1, 0)


def test_the_command_runs_beyond_with_its_options_and_refuses_them_elsewhere(tmp_path, monkeypatch, capsys):
    """``reproduce beyond --tuning-runs N --mlp-runs N`` reach the study; the figures refuse those options."""
    monkeypatch.setattr(beyond, "GRIDS", {name: grid[:1] for name, grid in GRIDS.items()})
    monkeypatch.setattr(beyond, "MAZES", {"paper maze": {}})
    monkeypatch.setattr(beyond, "SOURCE_TRANSITIONS", 200)
    monkeypatch.setattr(beyond, "ONLINE_TRANSITIONS", 20)
    command = [
        "reproduce",
        "beyond",
        "--runs",
        "2",
        "--tuning-runs",
        "2",
        "--mlp-runs",
        "1",
        "--workers",
        "1",
    ]
    assert main([*command, "--seed", "3", "--no-cache", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "beyond done" in printed and "beyond_improvement.png" in printed
    assert "| paper maze, MLP Q | OFUL |" in printed
    data = json.loads((tmp_path / "beyond.json").read_text())
    assert (data["parameters"]["tuning_runs"], data["parameters"]["mlp_runs"], data["seed"]) == (2, 1, 3)
    assert data["parameters"]["n_online"] == 20 and data["parameters"]["n_source"] == 200

    assert main(["reproduce", "fig5", "--tuning-runs", "2", "--out", str(tmp_path / "fig5")]) == 2
    assert "--tuning-runs: an option of 'reproduce beyond'" in capsys.readouterr().err
    assert not (tmp_path / "fig5").exists()
    for bad in (["--tuning-runs", "0"], ["--mlp-runs", "-1"]):
        with pytest.raises(SystemExit):
            main(["reproduce", "beyond", *bad])
        assert "expected an integer" in capsys.readouterr().err
    with pytest.raises(ValueError, match="takes no option"):
        reproduce("fig5", tmp_path, options={"mlp_runs": 1})
    assert "beyond" in STUDIES


def test_the_mazes_are_named_as_in_mazes_or_with_dashes_and_the_command_takes_them(tmp_path, capsys):
    assert beyond.mazes_named(["noise-by-cell"]) == {"noise by cell": {"reward_noise_std": CELL_NOISE_STDS}}
    assert list(beyond.mazes_named(["noise by cell", "paper-maze"])) == ["paper maze", "noise by cell"]
    with pytest.raises(ValueError, match="mazes must be among"):
        beyond.mazes_named([])
    assert main(["reproduce", "beyond", "--mazes", "paper", "--out", str(tmp_path)]) == 2
    assert "mazes must be among paper-maze, noise-by-cell, got ['paper']" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_the_tuning_runs_in_fewer_larger_batches_than_the_evaluation():
    """
    The tuning's runs in batches of ``TUNING_BATCH_RUNS`` (4 of 25 at the default 100), the evaluation's in
    20: the seeds the JSON records are those of the batches ``transfer_runs`` makes with ``source_sets``.
    """
    assert TUNING_BATCH_RUNS == 25
    assert [tuning_source_sets(runs) for runs in (1, 3, 25, 26, 50, 100)] == [1, 1, 1, 2, 2, 4]
    assert len(tuning_seeds(SEED, 100)["source_sets"]) == 4
    assert len(evaluation_seeds(SEED, 500)["source_sets"]) == batches.SOURCE_SETS == 20
    method = GRIDS[REFERENCE][0]
    found = batches.transfer_runs([method], range(25), 6, SEED, 1, n_source=40, n_online=4, source_sets=3)
    assert [record.source_set for record in found[method.label]] == [0, 0, 1, 1, 2, 2]
    assert evaluation_seeds(SEED, 6)["source_sets"] == [batches.source_seed(SEED, b) for b in range(6)]


def test_beyond_is_not_part_of_all_and_its_help_says_what_it_does(capsys):
    with pytest.raises(SystemExit):
        main(["reproduce", "--help"])
    help_text = capsys.readouterr().out
    assert "beyond" in help_text and "--tuning-runs" in help_text and "--mlp-runs" in help_text
    assert "stratified bootstrap" in help_text
    from sb3_trlsd_lab.registry import FIGURES

    assert "beyond" not in FIGURES


def test_the_grids_have_eight_configurations_per_method_at_the_paper_s_two_ratios():
    assert list(GRIDS) == [REFERENCE, "OFUL", "Thompson", "Bernstein"]
    heads = {REFERENCE: "ridge", "OFUL": "ridge_posterior", "Thompson": "thompson", "Bernstein": "bernstein"}
    for name, grid in GRIDS.items():
        assert len(grid) == 8 and len({c.label for c in grid}) == 8
        assert {c.update_ratio for c in grid} == {2.0, 1.2} and {c.reward_head for c in grid} == {heads[name]}
        assert len({c.kappa for c in grid}) == 4 and all(
            c.policy == "LinearPolicy" and c.transfer for c in grid
        )
    assert batches.SOURCE_TRANSITIONS == 25_000 and selection_window(1_000) == (500, 1_000)
