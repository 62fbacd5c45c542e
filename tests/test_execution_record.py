"""The runner's execution order (``softpend.after``) and execution record/page, on tiny synthetic books."""

from __future__ import annotations

import json
import platform
from pathlib import Path

import nbformat
import pytest
from support import NOTEBOOK_HEADER as HEADER

from softpend.study.book import BookLayout, _processor, execution_order, run_notebooks, toc_notebooks


def source(
    title: str,
    body: str = "print(greeting)",
    after: list[str] | None = None,
    book_runs: list[str] | None = None,
    realtime: object = None,
) -> str:
    front = {
        key: value
        for key, value in (("after", after), ("book_runs", book_runs), ("realtime", realtime))
        if value is not None
    }
    extra = "softpend:\n" + "".join(f"  {key}: {json.dumps(value)}\n" for key, value in front.items()) if front else ""
    return (
        HEADER.format(extra=extra) + f"\n# {title}\n\n```{{code-cell}} ipython3\n:tags: [parameters]\n\n"
        f"greeting = 'hello'\n```\n\n```{{code-cell}} ipython3\n{body}\n```\n"
    )


def make_book(root: Path, notebooks: dict[str, str], profiles: dict) -> Path:
    (root / "notebooks").mkdir(parents=True)
    (root / "book").mkdir()
    chapters = "\n".join(f"      - file: book/_generated/{name}" for name in notebooks)
    (root / "_toc.yml").write_text(
        f"format: jb-book\nroot: book/intro\nparts:\n  - caption: Figures\n    chapters:\n{chapters}\n"
        "  - caption: Appendix\n    chapters:\n      - file: book/_generated/execution\n"
    )
    (root / "book" / "profiles.yml").write_text(json.dumps(profiles))
    for name, text in notebooks.items():
        (root / "notebooks" / f"{name}.md").write_text(text)
    return root


def test_execution_order_waits_for_after_and_rejects_cycles():
    assert execution_order(["a", "b", "c"], {"a": ["c"]}) == ["b", "c", "a"]
    assert execution_order(["a", "b"], {"a": ["c"]}) == ["a", "b"]  # c not selected: nothing to wait for
    with pytest.raises(ValueError, match="wait for each other"):
        execution_order(["a", "b"], {"a": ["b"], "b": ["a"]})


def test_after_runs_late_enters_the_key_and_the_record_describes_the_run(tmp_path):
    # the ledger reads what "late" wrote: it must run after it although the toc lists it first
    ledger = source("Ledger", "import pathlib\nprint(pathlib.Path('late.txt').read_text())", after=["late"])
    late = source("Late", "import pathlib\npathlib.Path('late.txt').write_text(greeting)")
    root = make_book(tmp_path, {"ledger": ledger, "late": late}, {"quick": {"late": {"greeting": "hi"}}})
    assert toc_notebooks(root / "_toc.yml") == ["ledger", "late"]  # the execution page is not a notebook
    runs = run_notebooks(root, profile="quick", progress=False, overrides={})
    assert [run.name for run in runs] == ["late", "ledger"]
    layout = BookLayout.at(root)
    record = json.loads(layout.record_path.read_text())
    assert record["profile"] == "quick"
    entries = {entry["name"]: entry for entry in record["notebooks"]}
    assert [entry["name"] for entry in record["notebooks"]] == ["ledger", "late"]  # toc order
    assert entries["late"]["title"] == "Late" and entries["late"]["this_run"] == "executed"
    assert entries["ledger"]["profile"] == "quick" and entries["late"]["executed_s"] > 0
    assert entries["late"]["executed_at"].startswith(record["date"][:4])
    machine = record["machine"]
    assert machine["python"] == platform.python_version() and machine["cpu_count"] >= 1
    assert machine["cpus_available"] >= 1 and machine["processor"] == _processor() not in ("", "-")
    page = layout.execution_page_path.read_text()
    assert page.startswith("(execution)=\n# Execution")
    assert f"| processor | {machine['processor']} |" in page and "| CPU cores |" in page
    assert "{doc}`Late <late>`" in page
    nb = nbformat.read(str(layout.output_path("late")), as_version=4)
    injected = [c for c in nb.cells if "injected-parameters" in c.metadata.get("tags", [])]
    assert len(injected) == 1 and "hide-input" in injected[0].metadata["tags"]  # folded in the book

    # cached: the record keeps its last execution and says the run took it from the cache
    first_s = entries["late"]["executed_s"]
    assert {run.status for run in run_notebooks(root, profile="quick", progress=False)} == {"cached"}
    entries = {e["name"]: e for e in json.loads(layout.record_path.read_text())["notebooks"]}
    assert entries["late"]["this_run"] == "cached" and entries["late"]["executed_s"] == first_s

    # a change upstream re-executes the notebook that runs after it (its key holds the upstream key) ...
    (root / "notebooks" / "late.md").write_text(late.replace("write_text(greeting)", "write_text(greeting * 2)"))
    runs = run_notebooks(root, profile="quick", progress=False, only=["late"], overrides={"greeting": "yo"})
    assert [(run.name, run.status) for run in runs] == [("late", "executed")]
    record = json.loads(layout.record_path.read_text())
    entries = {e["name"]: e for e in record["notebooks"]}
    assert entries["ledger"]["this_run"] == "not run" and record["overrides"] == {"greeting": "yo"}
    # ... also when it runs alone later
    assert [run.status for run in run_notebooks(root, profile="quick", progress=False, only=["ledger"])] == ["executed"]


def test_after_naming_an_unknown_notebook_fails_before_running(tmp_path):
    root = make_book(tmp_path, {"a": source("A", after=["nope"])}, {"quick": {}})
    with pytest.raises(ValueError, match="softpend.after must list other notebooks of _toc.yml, got \\['nope'\\]"):
        run_notebooks(root, profile="quick", progress=False)
    assert not BookLayout.at(root).output_path("a").exists()


def test_an_unknown_run_set_or_front_matter_key_is_rejected(tmp_path):
    from softpend.study.run_pool import book_jobs

    bad = make_book(tmp_path / "bad", {"x": source("X", book_runs=["ppo"])}, {"full": {}})
    with pytest.raises(ValueError, match=r"notebook 'x': run sets \(softpend.book_runs\) must be a list among"):
        book_jobs(bad, "full")  # softpend sweep --book, which trains them
    # the rig chapters run the twin in simulated time: `realtime: true` is gone, like any key the runner does not know
    rig = make_book(tmp_path / "rig", {"rig": source("Rig", realtime=True)}, {"full": {}})
    with pytest.raises(ValueError, match=r"^notebook 'rig': unknown front-matter key\(s\) softpend.realtime$"):
        run_notebooks(rig, profile="full", progress=False)


def test_the_page_shows_the_training_step_that_sweep_book_recorded(tmp_path, monkeypatch):
    """``softpend sweep --book`` writes book/_generated/training.json; the execution page reports it."""
    from softpend.cli import main
    from softpend.study import run_pool

    root = make_book(tmp_path, {"plain": source("Plain")}, {"full": {}})
    run_notebooks(root, profile="full", progress=False)
    assert "No training step recorded" in BookLayout.at(root).execution_page_path.read_text()
    trained = []
    monkeypatch.setattr(run_pool, "book_jobs", lambda root, profile: [("runs/x/dqn-seed0", (print, "x"))])
    # (the pool itself: run_pool._train, which no module imports by name)
    monkeypatch.setattr(run_pool, "_train", lambda jobs, *args: trained.extend(name for name, _ in jobs))
    assert main(["sweep", "--book", "--root", str(root), "--workers", "1"]) == 0
    assert trained == ["runs/x/dqn-seed0"]
    training = json.loads(BookLayout.at(root).training_path.read_text())
    assert training["profile"] == "full" and training["trained"] == trained and training["workers"] == 1
    run_notebooks(root, profile="full", progress=False)
    page = BookLayout.at(root).execution_page_path.read_text()
    assert "`softpend sweep --book --profile full`" in page and "trained 1 run(s)" in page


def test_notebooks_side_by_side_all_run_in_the_project_root(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPEND_WORKERS", "2")
    here = Path.cwd()
    # uneven lengths: executions end while others' kernels start
    body = "import os, pathlib, time\ntime.sleep({nap})\npathlib.Path('cwd-{name}.txt').write_text(os.getcwd())"
    notebooks = {
        name: source(name.upper(), body.format(nap=0.1 + 1.3 * (k % 2), name=name)) for k, name in enumerate("abcdef")
    }
    root = make_book(tmp_path, notebooks, {"full": {}})
    run_notebooks(root, profile="full", progress=False)
    assert Path.cwd() == here
    assert {name: (root / f"cwd-{name}.txt").read_text() for name in notebooks} == dict.fromkeys(
        notebooks, str(root.resolve())
    )
    assert not list(here.glob("cwd-*.txt"))


def test_the_processor_is_named_by_model_family_and_model(tmp_path):
    """Runs repeat exactly only on the same processor model, so the record names it (the first processor's
    fields of /proc/cpuinfo); without that file it falls back to what the platform module says."""
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(
        "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
        "model name\t: AMD EPYC\n\nprocessor\t: 1\ncpu family\t: 25\nmodel name\t: other\n"
    )
    assert _processor(cpuinfo) == "AMD EPYC (family 26, model 2)"
    assert _processor(tmp_path / "missing") == (platform.processor() or platform.machine() or "-")
