"""The notebook runner (softpend.study.book) on tiny synthetic books: validation, execution, failures, cache."""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import nbformat
import pytest
from support import NOTEBOOK_HEADER

from softpend.cli import main as cli_main
from softpend.study import book
from softpend.study.book import NotebookExecutionError, PackageCode, cache_key, run_notebooks, toc_notebooks

HEADER = NOTEBOOK_HEADER.format(extra="")


def notebook_source(*cells: str, parameters: str | None = "greeting = 'hello'\nrepeat = 1") -> str:
    """A jupytext MyST notebook with an optional parameters cell followed by code cells."""
    parts = [HEADER, "# A test notebook\n"]
    if parameters is not None:
        parts.append(f"```{{code-cell}} ipython3\n:tags: [parameters]\n\n{parameters}\n```\n")
    for cell in cells:
        parts.append(f"```{{code-cell}} ipython3\n{textwrap.dedent(cell).strip()}\n```\n")
    return "\n".join(parts)


OK_CELL = "print(greeting * repeat)"


def make_book(root: Path, notebooks: dict[str, str], profiles: dict) -> Path:
    """Write a minimal project (toc, profiles, notebook sources) under ``root``."""
    (root / "notebooks").mkdir(parents=True)
    (root / "book").mkdir()
    chapters = "\n".join(f"      - file: book/_generated/{name}" for name in notebooks)
    (root / "_toc.yml").write_text(
        f"format: jb-book\nroot: book/intro\nparts:\n  - caption: Figures\n    chapters:\n{chapters}\n"
    )
    (root / "book" / "profiles.yml").write_text(json.dumps(profiles))  # JSON is YAML
    for name, source in notebooks.items():
        (root / "notebooks" / f"{name}.md").write_text(source)
    return root


def outputs_text(path: Path) -> str:
    nb = nbformat.read(str(path), as_version=4)
    return "".join(
        out.get("text", "") for cell in nb.cells if cell.cell_type == "code" for out in cell.get("outputs", [])
    )


# ----------------------------------------------------------------------------- configuration
def test_toc_notebooks_keeps_reading_order_and_skips_plain_chapters(tmp_path):
    toc = tmp_path / "_toc.yml"
    toc.write_text(
        "format: jb-book\nroot: book/intro\nparts:\n"
        "  - caption: A\n    chapters:\n      - file: book/_generated/fig02\n      - file: book/method\n"
        "        sections:\n          - file: book/_generated/fig01.ipynb\n"
        "  - caption: B\n    chapters:\n      - file: book/_generated/fig03\n"
    )
    assert toc_notebooks(toc) == ["fig02", "fig01", "fig03"]
    toc.write_text(
        "format: jb-book\nroot: book/intro\nchapters:\n  - file: book/_generated/a\n  - file: book/_generated/a\n"
    )
    with pytest.raises(ValueError, match="more than once"):
        toc_notebooks(toc)


@pytest.mark.parametrize(
    "profiles, match",
    [
        ({"quick": {}}, "unknown profile 'full'"),
        ({"full": {"nb": {"nonexistent_parameter": 3}}}, "nonexistent_parameter"),
        ({"full": {"typo_notebook": {}}}, "typo_notebook"),
        ({"full": ["not", "a", "mapping"]}, "profile 'full'"),
        ({"full": {"nb": [1, 2]}}, "notebook 'nb'"),
    ],
)
def test_bad_profiles_raise_before_anything_runs(tmp_path, profiles, match):
    root = make_book(tmp_path, {"nb": notebook_source(OK_CELL)}, profiles)
    with pytest.raises(ValueError, match=match):
        run_notebooks(root, profile="full", progress=False)
    assert not (root / "book" / "_generated" / "nb.ipynb").exists()


def test_notebook_without_parameters_cell_is_rejected(tmp_path):
    root = make_book(
        tmp_path, {"good": notebook_source(OK_CELL), "bare": notebook_source(OK_CELL, parameters=None)}, {"full": {}}
    )
    with pytest.raises(ValueError, match="'bare' has no code cell tagged 'parameters'"):
        run_notebooks(root, progress=False)
    # validation happens before execution: the valid notebook listed first was not run either
    assert not (root / "book" / "_generated" / "good.ipynb").exists()


def test_unknown_only_name_and_missing_source(tmp_path):
    root = make_book(tmp_path, {"nb": notebook_source(OK_CELL)}, {"full": {}})
    with pytest.raises(ValueError, match="nope"):
        run_notebooks(root, only=["nope"], progress=False)
    (root / "notebooks" / "nb.md").unlink()
    with pytest.raises(FileNotFoundError, match="nb.md"):
        run_notebooks(root, progress=False)
    with pytest.raises(FileNotFoundError, match="_toc.yml"):
        run_notebooks(tmp_path / "elsewhere", progress=False)


def test_cli_reports_bad_profile_as_an_error(tmp_path, capsys):
    root = make_book(tmp_path, {"nb": notebook_source(OK_CELL)}, {"full": {}})
    assert cli_main(["book", "--root", str(root), "--profile", "nonexistent"]) == 2
    assert "unknown profile 'nonexistent'" in capsys.readouterr().err


# ----------------------------------------------------------------------------- execution and cache
def test_execution_injects_parameters_and_caches(tmp_path):
    # the notebook imports nothing from softpend, so edits of the package cannot touch its cache key
    profiles = {"full": {"nb": {"greeting": "full-profile ", "repeat": 2}}, "quick": {"nb": {"greeting": "quick "}}}
    root = make_book(tmp_path, {"nb": notebook_source(OK_CELL, "import os\nprint('cwd=' + os.getcwd())")}, profiles)
    output = root / "book" / "_generated" / "nb.ipynb"

    [first] = run_notebooks(root, profile="full", progress=False)
    assert first.status == "executed" and first.output_path == output
    text = outputs_text(output)
    assert "full-profile full-profile " in text
    assert f"cwd={root.resolve()}" in text  # notebooks run from the project root
    nb = nbformat.read(str(output), as_version=4)
    assert any("injected-parameters" in cell.metadata.get("tags", []) for cell in nb.cells)
    assert nb.metadata["softpend"]["profile"] == "full"

    # unchanged source, parameters and package: served from the cache, output untouched
    mtime = output.stat().st_mtime_ns
    [second] = run_notebooks(root, profile="full", progress=False)
    assert second.status == "cached" and output.stat().st_mtime_ns == mtime

    # different parameters (another profile) -> executed again
    [third] = run_notebooks(root, profile="quick", progress=False)
    assert third.status == "executed" and "quick " in outputs_text(output)

    # edited source -> executed again; --force executes even when up to date
    source = root / "notebooks" / "nb.md"
    source.write_text(source.read_text().replace(OK_CELL, OK_CELL + "\nprint('edited')"))
    [fourth] = run_notebooks(root, profile="quick", progress=False)
    assert fourth.status == "executed" and "edited" in outputs_text(output)
    assert run_notebooks(root, profile="quick", progress=False)[0].status == "cached"
    assert run_notebooks(root, profile="quick", force=True, progress=False)[0].status == "executed"


def test_overrides_apply_where_defined_and_unknown_ones_fail(tmp_path, capsys):
    """``--set NAME=VALUE`` (e.g. ``plant=beam``) lands in every notebook that defines NAME, on top of the
    profile; a notebook without it runs with its profile; a NAME no notebook defines fails before running."""
    notebooks = {
        "with_plant": notebook_source("print('plant=' + plant)", parameters="plant = 'prb'"),
        "without": notebook_source(OK_CELL),
    }
    root = make_book(tmp_path, notebooks, {"full": {"with_plant": {"plant": "prb"}}})
    runs = run_notebooks(root, profile="full", progress=False, overrides={"plant": "beam"})
    assert [r.status for r in runs] == ["executed", "executed"]
    assert "plant=beam" in outputs_text(root / "book" / "_generated" / "with_plant.ipynb")
    assert "hello" in outputs_text(root / "book" / "_generated" / "without.ipynb")
    # the override is part of the cache key: back to the profile value re-executes
    assert run_notebooks(root, profile="full", progress=False, only=["with_plant"])[0].status == "executed"

    with pytest.raises(ValueError, match="plnat"):
        run_notebooks(root, profile="full", progress=False, overrides={"plnat": "beam"})
    assert cli_main(["book", "--root", str(root), "--set", "plant"]) == 2
    assert "NAME=VALUE" in capsys.readouterr().err
    assert cli_main(["book", "--root", str(root), "--only", "without", "--set", "plant=beam"]) == 2
    assert "not parameters of any selected notebook" in capsys.readouterr().err


def test_each_executed_notebook_ends_with_its_rerun_section_and_the_command_works(tmp_path):
    """Issue 63: the runner appends "Rerun this figure": the parameters of the notebook's ``parameters`` cell
    with their defaults, units (a ``[unit]`` in the comment, else the name's suffix) and this build's values, and
    the command that reruns it; that command runs."""
    parameters = "duration_s = 2.0  # length of the run\ntilt = 0.1  # start tilt [deg]\nplant = 'prb'"
    root = make_book(
        tmp_path,
        {"fig_a": notebook_source("print(duration_s, plant)", parameters=parameters)},
        {"full": {"fig_a": {"duration_s": 1.0}}},
    )
    run_notebooks(root, progress=False)
    output = root / "book" / "_generated" / "fig_a.ipynb"
    last = nbformat.read(str(output), as_version=4).cells[-1]
    assert last.cell_type == "markdown" and last.source.startswith("## Rerun this figure")
    assert "| `duration_s` | `2.0` | `1.0` | s | length of the run |" in last.source
    assert "| `tilt` | `0.1` |  | deg | start tilt [deg] |" in last.source
    assert "| `plant` | `prb` |  |  |  |" in last.source
    assert "softpend book --only fig_a --set duration_s=2.0" in last.source
    assert cli_main(["book", "--root", str(root), "--only", "fig_a", "--set", "duration_s=3.0"]) == 0
    last = nbformat.read(str(output), as_version=4).cells[-1]
    assert "| `duration_s` | `2.0` | `3.0` | s |" in last.source and "3.0 prb" in outputs_text(output)


def test_parameters_that_do_not_evaluate_show_their_expression():
    rows = book.notebook_parameters("limit_nm = SOMEWHERE.limit  # the limit\nwidth_mm = 3")
    assert [(r["name"], r["default"], r["unit"], r["evaluated"]) for r in rows] == [
        ("limit_nm", "SOMEWHERE.limit", "N m", False),
        ("width_mm", "3", "mm", False),
    ]
    assert book.notebook_parameters("sizes = [16, 16]  # hidden widths [16, 16]")[0]["unit"] == ""


def test_cache_key_covers_source_parameters_and_code():
    key = cache_key("source", {"a": 1}, {"pkg": "h"})
    assert cache_key("source", {"a": 1}, {"pkg": "h"}) == key
    assert cache_key("source!", {"a": 1}, {"pkg": "h"}) != key
    assert cache_key("source", {"a": 2}, {"pkg": "h"}) != key
    assert cache_key("source", {"a": 1}, {"pkg": "h2"}) != key
    assert cache_key("source", {"a": 1}, {"pkg": "h", "pkg.mod": "h"}) != key


def write_package(root: Path, files: dict[str, str]) -> Path:
    """A fake package ``root/fakepkg`` with ``files`` (relative path -> source); returns its directory."""
    package = root / "fakepkg"
    for relative, text in files.items():
        path = package / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return package


FAKE_PACKAGE = {
    "__init__.py": '''\
        """The fake package."""
        ENTRY = {"thing": "fakepkg.plants.model:Model"}  # an entry point, imported by name when used
        ''',
    "plants/__init__.py": "from fakepkg.plants.registry import make\n",
    "plants/registry.py": '''\
        """Registry: names -> entry points."""
        _PLANTS = {"model": "fakepkg.plants.model:Model"}

        def make(name):
            from .helpers import load  # relative, inside a function
            return load(_PLANTS[name])
        ''',
    "plants/helpers.py": "import importlib\n\ndef load(entry):\n    return importlib.import_module(entry.split(':')[0])\n",
    "plants/model.py": '''\
        """The model."""
        from fakepkg.maths import gain


        class Model:
            """A model."""

            def step(self, x):
                """One step."""
                return gain.K * x  # scaled
        ''',
    "maths/__init__.py": "",
    "maths/gain.py": '''\
        """Gains."""
        K = 2.0  #: the gain
        ''',
    "unused/__init__.py": "",
    "unused/loop.py": "from fakepkg.maths import gain\nLOOPS = 3\n",
}

#: A notebook's code cells: one imports a submodule through ``from package import submodule``.
CELLS = ["value = 1", "from fakepkg.plants import registry\nregistry.make('model')"]


def test_closure_follows_imports_entry_points_and_parents(tmp_path):
    code = PackageCode(write_package(tmp_path, FAKE_PACKAGE))
    used = code.closure(CELLS)
    # the registry, its parent package, the root __init__, the relative import inside a function, and the
    # model that only an entry-point string names, with the model's own import and that one's package
    assert used == {
        "fakepkg",
        "fakepkg.plants",
        "fakepkg.plants.registry",
        "fakepkg.plants.helpers",
        "fakepkg.plants.model",
        "fakepkg.maths",
        "fakepkg.maths.gain",
    }
    # any import runs the root __init__, whose entry point reaches the model (and so the plants package)
    assert code.closure(["import fakepkg.unused.loop"]) == used | {"fakepkg.unused", "fakepkg.unused.loop"}
    assert code.closure(["import numpy as np\nfrom os import path"]) == set()


def key_of(package: Path) -> str:
    return cache_key("notebook source", {"p": 1}, PackageCode(package).code_hashes(CELLS))


@pytest.mark.parametrize(
    "path, old, new, changes",
    [
        ("maths/gain.py", "K = 2.0", "K = 3.0", True),  # code of a module used through two imports
        ("plants/model.py", "gain.K * x", "gain.K * x + 1", True),  # reached only through an entry point
        ("plants/helpers.py", "split(':')[0]", "split(':')[-1]", True),  # imported inside a function
        ("maths/gain.py", '"""Gains."""', '"""Gains, rewritten."""', False),  # module docstring
        ("plants/model.py", '"""One step."""', '"""One step of the model."""', False),  # method docstring
        ("plants/model.py", "# scaled", "# scaled by the gain", False),  # comment
        ("plants/model.py", "class Model:", "\n\nclass Model:", False),  # blank lines
        ("unused/loop.py", "LOOPS = 3", "LOOPS = 4", False),  # code of a module the notebook does not use
    ],
)
def test_cache_key_follows_the_code_a_notebook_uses(tmp_path, path, old, new, changes):
    package = write_package(tmp_path, FAKE_PACKAGE)
    before = key_of(package)
    target = package / path
    text = target.read_text()
    assert old in text
    target.write_text(text.replace(old, new))
    assert (key_of(package) != before) == changes


def test_cache_key_ignores_bytecode_and_counts_data_files(tmp_path):
    package = write_package(tmp_path, FAKE_PACKAGE)
    before = key_of(package)
    (package / "maths" / "__pycache__").mkdir()
    (package / "maths" / "__pycache__" / "gain.cpython-311.pyc").write_bytes(b"junk")
    assert key_of(package) == before
    (package / "maths" / "table.json").write_text("[1, 2]")
    with_data = key_of(package)
    assert with_data != before
    (package / "maths" / "table.json").write_text("[1, 3]")
    assert key_of(package) != with_data


def test_unparsable_cell_uses_every_module(tmp_path):
    code = PackageCode(write_package(tmp_path, FAKE_PACKAGE))
    assert code.closure(["def broken(:"]) == set(code.modules)
    assert code.closure(["%time x = 1"]) == set()  # IPython magics are translated before parsing


def test_real_notebook_closure_reaches_the_plant_and_not_pilco():
    root = Path(__file__).resolve().parents[1]
    code = PackageCode()
    assert code.name == "softpend"
    nb = book.read_notebook(root / "notebooks" / "fig01_prb_rod.md")
    used = code.closure(cell.source for cell in nb.cells if cell.cell_type == "code")
    assert {
        "softpend",
        "softpend.plant",
        "softpend.plant.registry",
        "softpend.plant.prb",
        "softpend.study.rod_design",
    } <= used
    assert "softpend.plant.beam" in used  # named only by the registry's entry point
    assert "softpend.pilco.loop" not in used and "softpend.rl.dqn" not in used
    assert all(len(value) == 64 for value in code.code_hashes(["import softpend.plant"]).values())


def test_code_change_invalidates_the_cache(tmp_path, monkeypatch):
    root = make_book(tmp_path, {"nb": notebook_source(OK_CELL)}, {"full": {}})
    monkeypatch.setattr(book.PackageCode, "code_hashes", lambda self, cells: {"softpend.plant": "one"})
    assert run_notebooks(root, progress=False)[0].status == "executed"
    assert run_notebooks(root, progress=False)[0].status == "cached"
    monkeypatch.setattr(book.PackageCode, "code_hashes", lambda self, cells: {"softpend.plant": "two"})
    assert run_notebooks(root, progress=False)[0].status == "executed"


def test_failing_notebook_names_notebook_and_cell_and_keeps_partial_output(tmp_path):
    source = notebook_source(
        OK_CELL, "print('before the failure')", "raise RuntimeError('deliberate failure')", "print('never')"
    )
    root = make_book(tmp_path, {"broken": source}, {"full": {}})
    with pytest.raises(NotebookExecutionError) as info:
        run_notebooks(root, progress=False)
    error = info.value
    message = str(error)
    assert "'broken'" in message and "deliberate failure" in message and "RuntimeError" in message
    assert "raise RuntimeError" in message  # the failing cell's first line
    assert error.code_cell_number == 4  # parameters, print, print, raise
    assert "code cell 4 of notebooks/broken.md" in message
    assert "raise RuntimeError" in book.read_notebook(root / "notebooks" / "broken.md").cells[error.cell_index].source
    text = outputs_text(error.output_path)
    assert "before the failure" in text and "never" not in text
    assert not (root / "book" / "_generated" / "broken.sha256").exists()  # a failure is never cached
    assert cli_main(["book", "--root", str(root)]) == 1  # and the CLI exits non-zero


@pytest.mark.parametrize("folder, name", [("records", "greybox_route.json"), ("hparams", "dqn.yml")])
def test_data_files_enter_the_key_of_the_notebooks_whose_code_reads_them(tmp_path, folder, name):
    """softpend.study.records reads book/records/, softpend.study.presets book/hparams/: editing one changes the
    hashes that go into the key of every notebook using that code."""
    from softpend.study.book import _file_hashes

    path = tmp_path / "book" / folder
    assert _file_hashes(path, f"book/{folder}") == {}  # absent
    path.mkdir(parents=True)
    assert _file_hashes(path, f"book/{folder}") == {}
    data = path / name
    data.write_text("a: []\n")
    first = _file_hashes(path, f"book/{folder}")
    data.write_text("a: [1]\n")
    assert set(first) == {f"book/{folder}/{name}"} and _file_hashes(path, f"book/{folder}") != first
