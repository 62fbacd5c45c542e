"""The appendix's record of settings tried (book/records/what_we_tried.yml): it loads, has the fields the
appendix notebook uses, and the summaries are computed from it."""

from __future__ import annotations

from pathlib import Path

import pytest

from softpend.study.records import (
    current_pilco_runs,
    current_rl_runs,
    detail_rows,
    load_records,
    run_rows,
    summary_rows,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
RECORDS = REPO_ROOT / "book" / "records" / "what_we_tried.yml"

#: The methods whose current runs the appendix notebook reads from the run folders.
CURRENT = ("dqn_mbpo", "dqn", "pilco")


def test_the_record_loads_with_the_fields_the_appendix_uses():
    records = load_records(RECORDS)
    assert set(CURRENT) <= set(records)
    for key, method in records.items():
        for field in ("title", "measure", "unit", "legend", "budget"):
            assert isinstance(method[field], str), (key, field)
        assert method["runs"], key
        for run in method["runs"] + method["diagnostics"]:
            assert isinstance(run["setting"], str) and run["setting"] and isinstance(run["notes"], str)
            assert set(run["outcome"]) == (set(run["seeds"]) or {"all"}), run["setting"]
            assert set(run.get("details", {})) <= set(run["outcome"]), run["setting"]
        if method["unit"]:  # a method with a measure records the runs of its defaults, or the book runs them
            assert any(run.get("defaults") for run in method["runs"]) or method.get("defaults_run_by_the_book"), key
        rows, columns = run_rows(method)
        assert len(rows) == len(method["runs"]) and {"row", "setting", "notes"} <= set(columns)
        assert all(set(row) == set(columns) for row in rows)
        assert all(row["seed"] in method["runs"][row["row"] - 1]["outcome"] for row in detail_rows(method))


def test_summaries_count_a_run_that_never_balanced_as_infinitely_late():
    method = {
        "title": "m",
        "measure": "plant s to balance",
        "unit": "plant s",
        "legend": "",
        "budget": "",
        "runs": [
            {"setting": "a", "seeds": [0, 1, 2], "outcome": {0: 10, 1: "never", 2: 30}, "notes": "", "defaults": True},
            {"setting": "b", "seeds": [3, 4], "outcome": {3: 20, 4: "-"}, "notes": "", "defaults": True},
            {"setting": "c", "seeds": [], "outcome": {"all": "no seed got up"}, "notes": ""},
        ],
        "diagnostics": [],
    }
    rows, _ = run_rows(method)
    assert [(r["balanced"], r["median"]) for r in rows] == [("2 of 3", "30"), ("1 of 1", "20"), ("", "")]
    assert rows[0]["seed 3"] == "" and rows[2]["all seeds"] == "no seed got up"
    (summary,) = summary_rows({"m": method})
    assert summary["seeds"] == "0, 1, 2, 3, 4" and summary["balanced"] == "3 of 4" and summary["median"] == "25"


@pytest.mark.parametrize(
    "text, field",
    [
        ("methods: {m: {title: m}}", "lacks"),
        (
            "methods: {m: {title: m, measure: x, unit: s, legend: '', budget: '', diagnostics: [],\n"
            "  runs: [{setting: a, seeds: [0, 1], outcome: {0: 5}, notes: ''}]}}",
            "outcome",
        ),
        (
            "methods: {m: {title: m, measure: x, unit: s, legend: '', budget: '', diagnostics: [],\n"
            "  runs: [{setting: a, seeds: [zero], outcome: {zero: 5}, notes: ''}]}}",
            "seeds",
        ),
        ("methods: []", "methods"),
    ],
)
def test_a_malformed_record_is_a_value_error_naming_the_field(tmp_path, text, field):
    path = tmp_path / "records.yml"
    path.write_text(text)
    with pytest.raises(ValueError, match=field):
        load_records(path)


def test_current_runs_are_empty_without_run_folders(tmp_path):
    assert current_rl_runs(tmp_path / "rl", "mbpo", [0, 1]) == []
    assert current_pilco_runs(tmp_path / "pilco", [0]) == []


def test_current_runs_are_read_from_the_run_folders(tmp_path):
    from softpend.pilco import GPSettings, OptimiserSettings, PilcoConfig, PolicySettings, run_pilco
    from softpend.rl.config import DQNConfig
    from softpend.rl.dqn import train_dqn

    _, log = train_dqn(
        DQNConfig(episode_s=0.5, learning_starts=10, eval_seeds=(0,), eval_duration_s=0.5),
        seed=1,
        episodes=2,
        run_dir=tmp_path / "rl" / "dqn-seed1",
        progress=False,
    )
    (run,) = current_rl_runs(tmp_path / "rl", "dqn", [0, 1])  # seed 0 has no folder
    assert run["seeds"] == [1] and run["details"] == {1: "2 episodes"}
    assert run["outcome"][1] == (
        log.real_s_to_balance() if log.first_balanced() else f"never within {log.plant_s:g} plant s"
    )
    result = run_pilco(
        PilcoConfig(
            state="tip",
            horizon_s=1.0,
            prediction_s=None,
            n_policy_trials=1,
            policy=PolicySettings(n_basis=5),
            gp=GPSettings(max_points=15, iterations=5),
            optimiser=OptimiserSettings(iterations=3),
            eval_seeds=(1000,),
            eval_duration_s=1.0,
            compiled=False,
        ),
        progress=False,
    )
    result.save(tmp_path / "pilco" / "pilco-seed0")
    (run,) = current_pilco_runs(tmp_path / "pilco", [0, 2])
    assert run["seeds"] == [0] and "1 policy trials" in run["details"][0]
    expected = result.real_seconds_to_balance
    assert run["outcome"][0] == (
        expected if expected < float("inf") else f"not within {result.plant_seconds_total:g} s"
    )
