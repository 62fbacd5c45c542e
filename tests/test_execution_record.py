"""The runner's execution order (``softpend.after``) and execution record/page, on tiny synthetic books."""

from __future__ import annotations

import json
import platform
from pathlib import Path

import nbformat
import pytest

from support import NOTEBOOK_HEADER as HEADER

from softpend.study.book import BookLayout, _processor, execution_order, run_notebooks, toc_notebooks



def source(title: str, body: str = "print(greeting)", after: list[str] | None = None,
           book_runs: list[str] | None = None, realtime: object = None) -> str:
    front = {key: value for key, value in (("after", after), ("book_runs", book_runs), ("realtime", realtime))
             if value is not None}
    extra = "softpend:\n" + "".join(f"  {key}: {json.dumps(value)}\n" for key, value in front.items()) if front else ""
    return (HEADER.format(extra=extra) + f"\n# {title}\n\n```{{code-cell}} ipython3\n:tags: [parameters]\n\n"
            f"greeting = 'hello'\n```\n\n```{{code-cell}} ipython3\n{body}\n```\n")


def make_book(root: Path, notebooks: dict[str, str], profiles: dict, lock: str = "") -> Path:
    (root / "notebooks").mkdir(parents=True)
    (root / "book").mkdir()
    chapters = "\n".join(f"      - file: book/_generated/{name}" for name in notebooks)
    (root / "_toc.yml").write_text(
        f"format: jb-book\nroot: book/intro\nparts:\n  - caption: Figures\n    chapters:\n{chapters}\n"
        "  - caption: Appendix\n    chapters:\n      - file: book/_generated/execution\n")
    (root / "book" / "profiles.yml").write_text(json.dumps(profiles))
    (root / "environment.lock").write_text(lock)
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
    root = make_book(tmp_path, {"ledger": ledger, "late": late},
                     {"quick": {"late": {"greeting": "hi"}}},
                     lock="# Python 3.11.7\npytest==0.0.1\nnot-a-package-softpend==1.0\n")
    assert toc_notebooks(root / "_toc.yml") == ["ledger", "late"]  # the execution page is not a notebook
    runs = run_notebooks(root, profile="quick", progress=False, overrides={})
    assert [run.name for run in runs] == ["late", "ledger"]
    layout = BookLayout.at(root)
    record = json.loads(layout.record_path.read_text())
    assert record["profile"] == "quick"
    entries = {entry["name"]: entry for entry in record["notebooks"]}
    assert [entry["name"] for entry in record["notebooks"]] == ["ledger", "late"]  # toc order
    assert entries["late"]["title"] == "Late" and entries["late"]["this_run"] == "executed"
    assert entries["late"]["parameters"] == {"greeting": "hi"} and entries["late"]["overrides"] == {}
    assert entries["ledger"]["parameters"] == {} and entries["ledger"]["profile"] == "quick"
    assert entries["late"]["executed_s"] > 0 and entries["late"]["executed_at"].startswith(record["date"][:4])
    env = record["environment"]
    assert env["python"] == platform.python_version() and env["lock_python"] == "3.11.7"
    assert env["cpu_count"] >= 1 and env["cpus_available"] >= 1
    assert env["processor"] == _processor() and env["processor"] not in ("", "-")
    packages = {p["name"]: p for p in env["packages"]}
    assert packages["pytest"]["locked"] == "0.0.1" and packages["pytest"]["installed"] not in (None, "0.0.1")
    assert packages["not-a-package-softpend"]["installed"] is None
    page = layout.execution_page_path.read_text()
    assert page.startswith("(execution)=\n# Execution")
    assert f"| processor | {env['processor']} |" in page
    assert "{doc}`Late <late>`" in page and "`greeting=\"hi\"`" in page and "not installed" in page
    nb = nbformat.read(str(layout.output_path("late")), as_version=4)
    injected = [c for c in nb.cells if "injected-parameters" in c.metadata.get("tags", [])]
    assert len(injected) == 1 and "hide-input" in injected[0].metadata["tags"]  # folded in the book

    # cached: the record keeps the wall time of the last execution and says the run took it from the cache
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
    assert entries["ledger"]["this_run"] == "not run" and entries["late"]["overrides"] == {"greeting": "yo"}
    assert record["overrides"] == {"greeting": "yo"}
    # ... also when it runs alone later
    assert [run.status for run in run_notebooks(root, profile="quick", progress=False, only=["ledger"])] == ["executed"]


def test_after_naming_an_unknown_notebook_fails_before_running(tmp_path):
    root = make_book(tmp_path, {"a": source("A", after=["nope"])}, {"quick": {}})
    with pytest.raises(ValueError, match="softpend.after names"):
        run_notebooks(root, profile="quick", progress=False)
    assert not BookLayout.at(root).output_path("a").exists()


def fake_pool(monkeypatch, wait_for: str = ""):
    """Replace the book's training pool: ``calls`` gets each pool's run sets and root, ``outputs`` the executed
    notebooks when it began; each run set is one fake run, announced finished (after the output of the
    notebook ``wait_for`` exists, if given: the pool then outlasts that notebook)."""
    import time

    from softpend.study import run_pool

    calls, outputs = [], []

    def book_run_jobs(run_sets, root="."):
        calls.append((list(run_sets), Path(root)))
        return [(f"{run_set}-seed0", (print, run_set)) for run_set in run_sets]

    def train_jobs(jobs, progress=True, background=False, on_finished=None):
        root = calls[-1][1]
        outputs.append(sorted(path.name for path in BookLayout.at(root).generated_dir.glob("*.ipynb")))
        deadline = time.monotonic() + 60
        while wait_for and not BookLayout.at(root).key_path(wait_for).exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        for name, _ in jobs:
            on_finished(name)
        return len(jobs)

    monkeypatch.setattr(run_pool, "book_run_jobs", book_run_jobs)
    monkeypatch.setattr(run_pool, "train_jobs", train_jobs)
    monkeypatch.setattr(run_pool, "book_run_names", lambda run_sets: frozenset(f"{s}-seed0" for s in run_sets))
    return calls, outputs


def test_with_one_worker_book_runs_are_trained_first_for_the_notebooks_that_execute_with_their_defaults(
        tmp_path, monkeypatch):
    """``softpend: {book_runs: [...]}``: with one worker, before any notebook executes, the runner trains the
    run sets of the notebooks that will execute with their own parameters (one pool); a notebook given other
    parameters trains its own runs, a cached one needs none; the record and page say what the pool did."""
    monkeypatch.setenv("SOFTPEND_WORKERS", "1")
    calls, outputs = fake_pool(monkeypatch)
    notebooks = {"rl": source("RL", book_runs=["rl"]), "both": source("Both", book_runs=["rl", "pilco"]),
                 "plain": source("Plain")}
    root = make_book(tmp_path, notebooks, {"full": {}, "quick": {"rl": {"greeting": "hi"}, "both": {"greeting": "hi"}}})
    run_notebooks(root, profile="full", progress=False)
    assert calls == [(["pilco", "rl"], root)]
    assert outputs == [[]]  # before any notebook executed
    record = json.loads(BookLayout.at(root).record_path.read_text())
    assert record["training_pool"]["trained"] == 2 and record["training_pool"]["run_sets"] == ["pilco", "rl"]
    assert not record["training_pool"]["background"]
    assert "this run trained 2 of the runs they read (pilco, rl) in one pool" in \
        BookLayout.at(root).execution_page_path.read_text()

    calls.clear()
    run_notebooks(root, profile="full", progress=False)  # everything cached: no notebook reads runs
    assert calls == [] and json.loads(BookLayout.at(root).record_path.read_text())["training_pool"] is None
    run_notebooks(root, profile="full", progress=False, only=["rl"], force=True)
    assert calls == [(["rl"], root)]
    calls.clear()
    run_notebooks(root, profile="quick", progress=False)  # other parameters: the notebooks train their own
    assert calls == []


def test_notebooks_that_need_no_runs_execute_while_the_pool_trains_in_the_background(tmp_path, monkeypatch):
    """With two workers the pool trains in the background: a notebook that reads no runs executes (and
    finishes) while it trains, the readers only after their runs; the page lists when each started."""
    monkeypatch.setenv("SOFTPEND_WORKERS", "2")
    calls, outputs = fake_pool(monkeypatch, wait_for="plain")
    notebooks = {"rl": source("RL", book_runs=["rl"]), "plain": source("Plain")}
    root = make_book(tmp_path, notebooks, {"full": {}})
    runs = run_notebooks(root, profile="full", progress=False)
    assert calls == [(["rl"], root)] and outputs == [[]]
    layout = BookLayout.at(root)
    record = json.loads(layout.record_path.read_text())
    pool, entries = record["training_pool"], {entry["name"]: entry for entry in record["notebooks"]}
    assert pool["background"] and pool["trained"] == 1
    # "plain" finished before the pool announced its run, and "rl" started only after that
    assert entries["plain"]["started_s"] + entries["plain"]["run_s"] <= pool["run_s"] <= entries["rl"]["started_s"]
    assert {run.name: run.status for run in runs} == {"rl": "executed", "plain": "executed"}
    page = layout.execution_page_path.read_text()
    assert "in one pool of workers at the lowest scheduling priority" in page and "| started [s] | wall [s] |" in page


def test_a_failing_notebook_lets_the_pool_finish_and_is_raised(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPEND_WORKERS", "2")
    calls, _ = fake_pool(monkeypatch)
    notebooks = {"rl": source("RL", book_runs=["rl"]), "bad": source("Bad", "raise RuntimeError('boom')")}
    root = make_book(tmp_path, notebooks, {"full": {}})
    with pytest.raises(Exception, match="boom"):
        run_notebooks(root, profile="full", progress=False)
    assert calls == [(["rl"], root)]
    assert not BookLayout.at(root).key_path("bad").exists()


def test_an_unknown_run_set_is_rejected(tmp_path):
    bad = make_book(tmp_path / "bad", {"x": source("X", book_runs=["ppo"])}, {"full": {}})
    with pytest.raises(ValueError, match="softpend.book_runs must be a list among"):
        run_notebooks(bad, profile="full", progress=False)


def test_a_real_time_notebook_executes_alone_after_the_training_pool(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPEND_WORKERS", "2")
    fake_pool(monkeypatch, wait_for="a")  # the pool trains until "a" has executed
    nap = "import time\ntime.sleep(1.0)"
    notebooks = {"rig": source("Rig", nap, realtime=True), "a": source("A", nap), "b": source("B", nap),
                 "c": source("C", nap), "rl": source("RL", nap, book_runs=["rl"])}
    root = make_book(tmp_path, notebooks, {"full": {}})
    run_notebooks(root, profile="full", progress=False)
    record = json.loads(BookLayout.at(root).record_path.read_text())
    entries = {entry["name"]: entry for entry in record["notebooks"]}
    spans = {name: (entry["started_s"], entry["started_s"] + entry["run_s"]) for name, entry in entries.items()}
    rig = spans.pop("rig")
    assert rig[0] >= record["training_pool"]["run_s"]  # first in the toc, but it waited for the pool
    assert all(end <= rig[0] or start >= rig[1] for start, end in spans.values()), (rig, spans)
    assert spans["b"][0] < spans["a"][1]  # the others share the lanes

    bad = make_book(tmp_path / "bad", {"x": source("X", realtime="yes")}, {"full": {}})
    with pytest.raises(ValueError, match="softpend.realtime must be true or false"):
        run_notebooks(bad, profile="full", progress=False)


def test_notebooks_side_by_side_all_run_in_the_project_root(tmp_path, monkeypatch):
    monkeypatch.setenv("SOFTPEND_WORKERS", "2")
    here = Path.cwd()
    # uneven lengths: executions end while others' kernels start
    body = "import os, pathlib, time\ntime.sleep({nap})\npathlib.Path('cwd-{name}.txt').write_text(os.getcwd())"
    notebooks = {name: source(name.upper(), body.format(nap=0.1 + 1.3 * (k % 2), name=name))
                 for k, name in enumerate("abcdef")}
    root = make_book(tmp_path, notebooks, {"full": {}})
    run_notebooks(root, profile="full", progress=False)
    assert Path.cwd() == here
    assert {name: (root / f"cwd-{name}.txt").read_text() for name in notebooks} == dict.fromkeys(notebooks,
                                                                                                 str(root.resolve()))
    assert not list(here.glob("cwd-*.txt"))


def test_the_processor_is_named_by_model_family_and_model(tmp_path):
    """Runs repeat exactly only on the same processor model, so the record names it (the first processor's
    fields of /proc/cpuinfo); without that file it falls back to what the platform module says."""
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
                       "model name\t: AMD EPYC\n\nprocessor\t: 1\ncpu family\t: 25\nmodel name\t: other\n")
    assert _processor(cpuinfo) == "AMD EPYC (family 26, model 2)"
    assert _processor(tmp_path / "missing") == (platform.processor() or platform.machine() or "-")
