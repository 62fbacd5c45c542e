"""The stored probe summaries (``book/records/*.json``) as the appendix's tables, and the book's current runs.

A record is ``{"title", "command", "settings", "figures", "rows"}``: the command that wrote it, settings (scalars),
figures (numbers; infinite as ``"inf"``) and one row per seed or rod (scalars or mappings; scalars rendered)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

#: The records' folder, relative to the project root.
RECORDS_DIR = Path("book/records")

#: A record's fields and their JSON types.
FIELDS = {"title": str, "command": str, "settings": dict, "figures": dict, "rows": list}

_SCALARS = (str, int, float, bool, type(None))


def check_record(data: Any, where: str) -> dict[str, Any]:
    """``data`` as a record (``"inf"`` figures made floats); ``ValueError`` naming ``where`` and the bad field."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: a record must be a JSON object, got {type(data).__name__}")
    if unknown := sorted(set(data) - set(FIELDS)):
        raise ValueError(f"{where}: unknown field {unknown[0]!r} (a record has {', '.join(FIELDS)})")

    def check(items: Any) -> None:  # (name, value, types, what it must be)
        for at, value, kind, what in items:
            if not isinstance(value, kind) or (isinstance(value, bool) and what == "a number"):
                shown = repr(value) if what == "a number" else type(value).__name__
                raise ValueError(f"{where}: {at} must be {what}, got {shown}")

    check((f"field {field!r}", data.get(field), kind, f"a {kind.__name__}") for field, kind in FIELDS.items())
    figures = {name: float(value) if value in ("inf", "-inf") else value for name, value in data["figures"].items()}
    check((f"settings.{name}", value, _SCALARS, "a scalar") for name, value in data["settings"].items())
    check((f"figures.{name}", value, (int, float), "a number") for name, value in figures.items())
    check((f"rows[{i}]", row, dict, "a mapping") for i, row in enumerate(data["rows"]))
    cells = [(f"rows[{i}].{name}", value) for i, row in enumerate(data["rows"]) for name, value in row.items()]
    check((at, value, (*_SCALARS, dict), "a scalar or a mapping") for at, value in cells)
    return data | {"figures": figures}


def load_record(path: Path | str) -> dict[str, Any]:
    """The record in the JSON file ``path``, checked (:func:`check_record`)."""
    from softpend.io.reading import MAX_JSON_BYTES, read_json_checked

    return check_record(read_json_checked(path, "probe record", MAX_JSON_BYTES), str(path))


def load_records(folder: Path | str = RECORDS_DIR) -> dict[str, dict[str, Any]]:
    """Every record in ``folder`` (``*.json``, not hidden) by file stem, in name order; ``ValueError`` when none."""
    paths = sorted(path for path in Path(folder).glob("*.json") if not path.name.startswith("."))
    if not paths:
        raise ValueError(f"{folder}: no probe records (*.json)")
    return {path.stem: load_record(path) for path in paths}


def record_text(record: Mapping[str, Any]) -> str:
    """``record`` as the JSON text a probe script stores (checked; numpy scalars as plain numbers)."""
    text = json.dumps(record, indent=1, default=lambda value: value.item() if hasattr(value, "item") else str(value))
    check_record(json.loads(text), f"record {record.get('title')!r}")
    return text + "\n"


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    return "" if value is None else str(value).replace("|", "\\|")


def markdown_rows(rows: Sequence[Mapping[str, Any]]) -> str:
    """A Markdown table of the scalar values of ``rows`` (a column per name, in order of first appearance)."""
    from softpend.study.figures.fidelity import markdown_table

    columns = list(dict.fromkeys(k for row in rows for k, v in row.items() if not isinstance(v, Mapping)))
    return markdown_table([{c: _cell(row.get(c)) for c in columns} for row in rows], columns)


def record_markdown(record: Mapping[str, Any], heading: str = "###") -> str:
    """One record as Markdown: its title, the command that wrote it, its settings, its figures and its rows."""
    settings = "; ".join(f"`{name}` = {_cell(value)}" for name, value in record["settings"].items())
    figures = [{"figure": name, "value": value} for name, value in record["figures"].items()]
    parts = [f"{heading} {record['title']}", f"Command: `{record['command']}`", f"Settings: {settings or 'none'}."]
    parts += [markdown_rows(figures)] if figures else ["Figures: none."]
    parts += [f"Rows ({len(record['rows'])}):", markdown_rows(record["rows"])] if record["rows"] else []
    return "\n\n".join(parts)


def current_rl_runs(runs_root: Path | str, algo: str, seeds: Sequence[int], plant: str = "prb") -> list[dict[str, Any]]:
    """The book's current runs of one RL method, a row per seed: plant seconds to balance, plant seconds, episodes."""
    from softpend.rl.config import load_config
    from softpend.rl.training_log import TrainingLog
    from softpend.study.rl_runs import load_runs

    def row(folder: Path, seed: int) -> dict[str, Any]:
        load_config(folder / "config.json")
        log = TrainingLog.load(folder / "log.json")
        return dict(
            seed=seed, plant_s_to_balance=float(log.real_s_to_balance()), plant_s=log.plant_s, episodes=log.n_episodes
        )

    return load_runs(runs_root, plant, algo, seeds, row)


def current_pilco_runs(runs_root: Path | str, seeds: Sequence[int], plant: str = "prb") -> list[dict[str, Any]]:
    """The book's current PILCO runs, a row per seed: plant seconds to balance and in all, policy trials, worst test
    std and training CPU seconds."""
    from softpend.pilco.loop import PilcoResult
    from softpend.study.rl_runs import load_runs

    def row(folder: Path, seed: int) -> dict[str, Any]:
        records = (result := PilcoResult.load(folder)).records
        row = {"seed": seed, "plant_s_to_balance": float(result.real_seconds_to_balance)}
        row |= {"plant_s": result.plant_seconds_total, "policy_trials": sum(r.kind == "policy" for r in records)}
        worst = records[-1].eval_upright_std_rad if records else math.nan
        return row | {"worst_test_std_rad": worst, "train_cpu_s": result.train_cpu_s}

    return load_runs(runs_root, plant, "pilco", seeds, row)


def balance_summary(rows: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """The seeds of current-run rows, how many balanced (``"k of n"``) and the median plant seconds to balance."""
    values = [float(row["plant_s_to_balance"]) for row in rows]
    median = float(np.median(values)) if values else math.nan
    balanced = f"{sum(map(math.isfinite, values))} of {len(values)}"
    return {"seeds": ", ".join(str(row["seed"]) for row in rows), "balanced": balanced, "median": _cell(median)}


def plot_current(current: Mapping[str, Sequence[Mapping[str, Any]]]):
    """One line per method: each seed's plant seconds to balance (crosses at the grey line: did not balance)."""
    import matplotlib.pyplot as plt

    labels = [label for label, rows in current.items() if rows]
    finite = [r["plant_s_to_balance"] for k in labels for r in current[k] if math.isfinite(r["plant_s_to_balance"])]
    edge = 1.15 * max(finite) if finite else 1.0
    fig, ax = plt.subplots(figsize=(8, 1.2 + 0.5 * len(labels)))
    for number, label in enumerate(labels):
        for row in current[label]:
            value = row["plant_s_to_balance"]
            ax.plot(value if math.isfinite(value) else edge, number, "o" if math.isfinite(value) else "x", color="C0")
    ax.axvline(edge, color="0.8", lw=0.8)
    ax.set_yticks(range(len(labels)), labels)
    ax.set_ylim(len(labels) - 0.5, -0.5)
    ax.set(xlim=(0, 1.05 * edge), xlabel="plant seconds to balance (crosses at the grey line: did not balance)")
    fig.tight_layout()
    return fig
