"""The paper's claims checked on figure JSONs: each rule on numbers whose verdict is known."""

from __future__ import annotations

import json

import pytest

from sb3_trlsd_lab.cli import main
from sb3_trlsd_lab.execution.protocols import PRESETS
from sb3_trlsd_lab.studies.claims import (
    CLAIMS,
    above,
    above_all,
    alike,
    claims_table,
    evaluate_claims,
    load_figures,
    more_sensitive,
    same_runs,
    solved_by,
    updates_near,
)


def aggregate(mean: float, se: float) -> dict:
    return {"mean": mean, "se": se}


def method(last_500: float, se: float = 0.01, updates: float = 80.0) -> dict:
    return {"reward": {"[500, 1000)": aggregate(last_500, se)}, "policy_updates": aggregate(updates, 0.5)}


def test_above_holds_past_two_standard_errors_of_the_difference():
    # Standard error of each difference: sqrt(2) * 0.01 = 0.0141.
    results = {"a": method(0.50), "b": method(0.475), "c": method(0.47)}
    short = above("a", "b", "reward", "[500, 1000)")(results)  # 1.77 SE
    assert short.z == pytest.approx(0.025 / 0.01 / 2**0.5)
    assert not short.holds
    assert above("a", "c", "reward", "[500, 1000)")(results).holds  # 2.12 SE
    assert not above("c", "a", "reward", "[500, 1000)")(results).holds


def test_alike_holds_within_two_standard_errors():
    results = {"a": method(0.50), "b": method(0.48), "c": method(0.45)}
    assert alike("a", "b", "reward", "[500, 1000)")(results).holds  # 1.4 SE
    assert not alike("a", "c", "reward", "[500, 1000)")(results).holds  # 3.5 SE


def test_above_all_needs_every_method_above_and_reports_the_least():
    results = {"a": method(0.60), "b": method(0.52), "low": method(0.50)}
    verdict = above_all(("a", "b"), "low", "reward", "[500, 1000)")(results)
    assert not verdict.holds and verdict.z == pytest.approx(0.02 / 0.01 / 2**0.5)
    assert "least of 2: 0.520" in verdict.measured
    assert above_all(("a",), "low", "reward", "[500, 1000)")(results).holds


def test_updates_near_and_solved_by_are_bounds():
    results = {"m": method(0.5, updates=76.7), "x": {"near_solved_after_episodes": 375}}
    assert not updates_near("m", 50, 0.25)(results).holds
    assert updates_near("m", 80, 0.25)(results).holds
    assert not solved_by(("x",), 300)(results).holds
    assert solved_by(("x",), 375)(results).holds


def test_more_sensitive_compares_the_ranges():
    results = {
        "k1": method(0.40),
        "k2": method(0.10),  # kappa range 0.30
        "s1": method(0.40),
        "s2": method(0.35),  # sigma range 0.05
    }
    assert more_sensitive(("k1", "k2"), ("s1", "s2"), "reward", "[500, 1000)")(results).holds
    assert not more_sensitive(("s1", "s2"), ("k1", "k2"), "reward", "[500, 1000)")(results).holds


def write_figure(
    directory, figure: str, results: dict, protocol: str | None, wall_time_seconds: float | None = None
) -> None:
    parameters = {} if protocol is None else {"protocol": {"name": protocol}}
    data = {"figure": figure, "parameters": parameters, "results": results}
    if wall_time_seconds is not None:
        data["wall_time_seconds"] = wall_time_seconds
    (directory / f"{figure}.json").write_text(json.dumps(data))


FIG8 = {
    label: {"near_solved_after_episodes": 250, "last_turn_reward": aggregate(mean, 0.005)}
    for label, mean in [
        ("non-optimistic (kappa=0)", 0.40),
        ("similarity on states (eq. 6)", 0.47),
        ("similarity on features (eq. 7)", 0.465),
    ]
}


def test_the_fig8_claims_hold_on_the_paper_s_picture_and_other_figures_stay_blank(tmp_path):
    write_figure(tmp_path, "fig8", FIG8, "multitask-continue")
    name, figures = load_figures(tmp_path)
    assert name == "multitask-continue"
    verdicts = evaluate_claims(figures)
    fig8 = [verdict for claim, verdict in zip(CLAIMS, verdicts, strict=True) if claim.figure == "fig8"]
    assert len(fig8) == 3 and all(verdict is not None and verdict.holds for verdict in fig8)
    assert all(
        verdict is None for claim, verdict in zip(CLAIMS, verdicts, strict=True) if claim.figure != "fig8"
    )
    table = claims_table([(name, figures)])
    assert table.splitlines()[0] == "| figure | paper's claim | multitask-continue |"
    assert len(table.splitlines()) == 2 + len(CLAIMS)


def test_a_figure_without_a_protocol_record_ran_under_as_built_and_protocols_do_not_mix(tmp_path):
    write_figure(tmp_path, "fig8", FIG8, None)
    assert load_figures(tmp_path)[0] == "as-built"
    write_figure(tmp_path, "fig5", {}, "gamma-0.99")
    with pytest.raises(ValueError, match="several protocols"):
        load_figures(tmp_path)


def test_the_claims_command_prints_and_writes_one_column_per_directory(tmp_path, capsys):
    first, second = tmp_path / "a", tmp_path / "b"
    first.mkdir(), second.mkdir()
    write_figure(first, "fig8", FIG8, None)
    lower = {label: dict(entry, near_solved_after_episodes=375) for label, entry in FIG8.items()}
    write_figure(second, "fig8", lower, "multitask-fixed-start")
    out = tmp_path / "claims.md"
    assert main(["claims", str(first), str(second), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| as-built | multitask-fixed-start |" in printed
    assert "250, 250, 250 episodes (paper: 300): holds" in printed
    assert "375, 375, 375 episodes (paper: 300): **does not hold**" in printed
    assert out.read_text().strip() == printed.strip()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["claims", str(empty)]) == 2


def test_a_protocol_s_figure_with_an_earlier_column_s_results_says_whose_runs_they_are(tmp_path):
    today, fixed, continued, both = (tmp_path / name for name in ("today", "fixed", "continued", "both"))
    for directory in (today, fixed, continued, both):
        directory.mkdir()
    timed = {label: dict(entry, seconds_per_run=1.0) for label, entry in FIG8.items()}
    write_figure(today, "fig8", timed, None)
    retimed = {label: dict(entry, seconds_per_run=2.0) for label, entry in FIG8.items()}
    write_figure(fixed, "fig8", retimed, "no-online-restarts")  # reaches no run of Figure 8
    moved = dict(
        FIG8,
        **{
            "non-optimistic (kappa=0)": dict(FIG8["non-optimistic (kappa=0)"], near_solved_after_episodes=260)
        },
    )
    write_figure(continued, "fig8", moved, "multitask-continue")
    write_figure(both, "fig8", moved, "no-restarts")  # runs Figure 8 as multitask-continue does
    table = claims_table([load_figures(directory) for directory in (today, fixed, continued, both)])
    solved_line = next(line for line in table.splitlines() if "near solved" in line)
    solved = solved_line.removesuffix(" |").split(" | ")
    assert solved[2].startswith("250, 250, 250 episodes")
    assert solved[3] == same_runs("as-built")
    assert solved[4].startswith("260, 250, 250 episodes")
    assert solved[5] == same_runs("multitask-continue")
    # Without an earlier column with those results there is nothing to refer to: the numbers are given.
    alone = claims_table([load_figures(directory) for directory in (fixed, continued)])
    assert "the same runs" not in alone and "250, 250, 250 episodes" in alone


def test_the_runs_table_gives_wall_times_kept_runs_and_presets_not_run(tmp_path, capsys):
    directories = {name: tmp_path / name for name in ("full", "continue", "both", "fixed")}
    for directory in directories.values():
        directory.mkdir()
    write_figure(directories["full"], "fig8", FIG8, None, wall_time_seconds=3270.0)
    write_figure(directories["full"], "fig5", {"m": method(0.5)}, None, wall_time_seconds=935.0)
    continued = {label: dict(entry, near_solved_after_episodes=260) for label, entry in FIG8.items()}
    write_figure(directories["continue"], "fig8", continued, "multitask-continue", wall_time_seconds=2646.0)
    # A combination that reaches Figure 8 as the single change does: the same runs, read in a second.
    write_figure(directories["both"], "fig8", continued, "no-restarts", wall_time_seconds=1.3)
    write_figure(directories["both"], "fig5", {"m": method(0.6)}, "no-restarts", wall_time_seconds=630.0)
    write_figure(directories["fixed"], "fig8", FIG8, "multitask-fixed-start")  # no wall time kept
    assert main(["claims", *map(str, directories.values()), "--runs"]) == 0
    rows = {line.split(" | ")[0].strip("| `"): line for line in capsys.readouterr().out.splitlines()}
    assert rows["preset"] == "| preset | Figure 5 | Figure 6 | Figure 7 | Figure 8 |"
    assert rows["as-built"] == "| `as-built` | 15.6 min | not run | not run | 54.5 min |"
    assert rows["multitask-continue"] == "| `multitask-continue` | not run | not run | not run | 44.1 min |"
    assert (
        rows["no-restarts"]
        == "| `no-restarts` | 10.5 min | not run | not run | `multitask-continue`'s runs |"
    )
    assert rows["multitask-fixed-start"].endswith("| `as-built`'s runs |")
    assert rows["gamma-0.99"] == "| `gamma-0.99` | not run | not run | not run | not run |"
    # Every preset has a row, in the order ``--protocol`` lists them.
    assert [name for name in rows if name in PRESETS] == list(PRESETS)
