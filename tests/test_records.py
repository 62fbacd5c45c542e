"""The appendix's stored probe summaries (book/records/*.json): every one loads in the record schema, a
malformed one is refused naming the field, the render shows the stored figures; and the current runs are read
from the run folders."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from softpend.study.records import (
    FIELDS,
    balance_summary,
    current_pilco_runs,
    current_rl_runs,
    load_record,
    load_records,
    record_markdown,
    record_text,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
RECORDS = REPO_ROOT / "book" / "records"

GOOD = {
    "title": "a probe",
    "command": "scripts/probe.py --seeds 2",
    "settings": {"seeds": 2, "model": "residual"},
    "figures": {"median_plant_s": 12.345678, "worst_plant_s": "inf"},
    "rows": [{"seed": 0, "plant_s": 1.5, "rod": {"mass_kg": 0.1}}, {"seed": 1, "plant_s": math.inf, "note": None}],
}


def test_every_stored_record_loads_in_the_schema():
    records = load_records(RECORDS)
    assert records and all(path.stem in records for path in RECORDS.glob("[!.]*.json"))
    for name, record in records.items():
        assert set(record) == set(FIELDS), name
        assert record["title"] and "scripts/probe_" in record["command"] and record["rows"], name
        assert all(isinstance(v, (int, float)) for v in record["figures"].values()), name


def test_the_render_shows_the_stored_figures_and_rows(tmp_path):
    path = tmp_path / "probe.json"
    path.write_text(record_text(GOOD))
    record = load_record(path)
    assert record["figures"]["worst_plant_s"] == math.inf
    text = record_markdown(record)
    assert "### a probe" in text and "`scripts/probe.py --seeds 2`" in text and "`model` = residual" in text
    assert "| median_plant_s | 12.3457 |" in text and "| worst_plant_s | inf |" in text
    assert "| seed | plant_s | note |" in text and "| 1 | inf |  |" in text and "mass_kg" not in text
    for record in load_records(RECORDS).values():  # a stored figure appears in its record's table
        text = record_markdown(record)
        assert all(f"| {name} |" in text for name in record["figures"])


@pytest.mark.parametrize(
    "change, field",
    [
        ({"title": None}, "'title'"),
        ({"summary": {}}, "'summary'"),
        ({"settings": {"config": {"a": 1}}}, "settings.config"),
        ({"figures": {"median": "12 s"}}, "figures.median"),
        ({"figures": {"balanced": True}}, "figures.balanced"),
        ({"rows": [{"seed": 0}, {"seeds": [0, 1]}]}, r"rows\[1\].seeds"),
        ({"rows": [3]}, r"rows\[0\]"),
    ],
)
def test_a_malformed_record_is_a_value_error_naming_the_file_and_field(tmp_path, change, field):
    path = tmp_path / "probe.json"
    path.write_text(json.dumps(GOOD | change))
    with pytest.raises(ValueError, match=field) as info:
        load_record(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ValueError, match=field):
        record_text(GOOD | change)


def test_a_record_that_is_not_json_or_absent_is_a_value_error(tmp_path):
    (tmp_path / "probe.json").write_text("{")
    with pytest.raises(ValueError, match="probe.json"):
        load_records(tmp_path)
    with pytest.raises(ValueError, match="no probe records"):
        load_records(tmp_path / "absent")


def test_the_summary_counts_a_run_that_never_balanced_as_infinitely_late():
    rows = [{"seed": 0, "plant_s_to_balance": 10.0}, {"seed": 1, "plant_s_to_balance": math.inf}]
    rows.append({"seed": 2, "plant_s_to_balance": 30.0})
    assert balance_summary(rows) == {"seeds": "0, 1, 2", "balanced": "2 of 3", "median": "30"}
    assert balance_summary(rows[1:2])["median"] == "inf"


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
    assert run == {"seed": 1, "plant_s_to_balance": log.real_s_to_balance(), "plant_s": log.plant_s, "episodes": 2}
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
    assert run["seed"] == 0 and run["policy_trials"] == 1
    assert run["plant_s_to_balance"] == result.real_seconds_to_balance
    assert run["plant_s"] == result.plant_seconds_total


def test_a_hidden_json_file_beside_the_records_is_not_a_record(tmp_path):
    """A probe's output manifest (``.softpend-outputs.json``) lies beside the records it wrote: it is not read."""
    (tmp_path / "probe.json").write_text(record_text(GOOD))
    (tmp_path / ".softpend-outputs.json").write_text('{"files": {}}')
    assert list(load_records(tmp_path)) == ["probe"]
