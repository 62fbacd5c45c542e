"""The whole book built with the quick profile (the session fixture ``quick_book`` of ``conftest.py``, in a
temporary copy of the project), and the HTML it produces."""

from __future__ import annotations

import json
import re
from pathlib import Path

import nbformat

from softpend.study import book
from softpend.study.book import BookLayout, execution_order, front_matter, load_profiles, run_notebooks, toc_notebooks

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_every_toc_notebook_has_a_quick_profile_and_executes_cleanly(quick_book):
    root, runs, _ = quick_book
    names = toc_notebooks(root / "_toc.yml")
    assert names, "the toc lists no notebooks"
    after = {
        name: front_matter(book.read_notebook(root / "notebooks" / f"{name}.md"), name, names)["after"]
        for name in names
    }
    assert [run.name for run in runs] == execution_order(names, after)
    assert any(after.values()), "the claims ledger reads the chapters it lists in softpend.after"
    for name, deps in after.items():  # a notebook that reads others executes after them
        order = [run.name for run in runs]
        assert all(order.index(dep) < order.index(name) for dep in deps), name
    assert all(run.status == "executed" for run in runs)
    quick = load_profiles(root / "book" / "profiles.yml")["quick"]
    assert sorted(quick) == sorted(names), "every notebook needs a block in the quick profile"
    for run in runs:
        nb = nbformat.read(str(run.output_path), as_version=4)
        errors = [out for cell in nb.cells for out in cell.get("outputs", []) if out.output_type == "error"]
        assert not errors, f"{run.name}: {errors}"
    assert not list((root / "kernel-tmp").glob("softpend-*")), "a notebook left its temporary folder behind"
    # a second run is served by the execution cache, and the execution record says so
    assert {run.status for run in run_notebooks(root, profile="quick", progress=False)} == {"cached"}
    record = json.loads(BookLayout.at(root).record_path.read_text())
    assert [entry["name"] for entry in record["notebooks"]] == names
    assert all(
        entry["this_run"] == "cached" and entry["executed_s"] > 0 and entry["profile"] == "quick"
        for entry in record["notebooks"]
    )


def test_execution_page_is_in_the_book_and_lists_every_notebook(quick_book):
    root, runs, html_dir = quick_book
    page = html_dir / "book" / "_generated" / "execution.html"
    assert page.is_file()
    text = re.sub(r"<[^>]+>", "", page.read_text(encoding="utf-8"))
    for run in runs:  # each notebook's row links to its page
        assert f'href="{run.name}.html"' in page.read_text(encoding="utf-8"), run.name
    assert "--profile quick" in text and "environment.lock" in text and "CPU cores" in text and "processor" in text
    # the training step of the build (the fixture trains as `make book` does) is on the page, with what it trained
    training = json.loads(BookLayout.at(root).training_path.read_text())
    assert training["profile"] == "quick" and training["trained"], training
    assert "softpend sweep --book --profile quick" in text and f"{len(training['trained'])} run(s)" in text


def test_every_chapter_ends_with_its_generated_rerun_section(quick_book):
    """Issue 63: the runner appends "Rerun this figure" (parameters, defaults, units, the command) to each page."""
    root, _, html_dir = quick_book
    for name in toc_notebooks(root / "_toc.yml"):
        text = re.sub(r"<[^>]+>", "", (html_dir / "book" / "_generated" / f"{name}.html").read_text(encoding="utf-8"))
        assert re.search(r"Rerun this (figure|chapter)", text), name
        assert f"softpend book --only {name} --profile quick --set " in text, name


#: Notebooks whose page is a table, not a figure (the appendix plots the full profile's runs, absent in a quick build).
NO_FIGURE = {"claims_ledger", "appendix_what_we_tried"}


def test_html_pages_exist_and_embed_png_figures(quick_book):
    root, _, html_dir = quick_book
    assert html_dir == root.resolve() / "_build" / "html"
    assert (html_dir / "index.html").is_file()
    assert (html_dir / "book" / "intro.html").is_file()
    for name in toc_notebooks(root / "_toc.yml"):
        page = html_dir / "book" / "_generated" / f"{name}.html"
        assert page.is_file(), f"no HTML page for {name}"
        if name in NO_FIGURE:
            continue
        sources = re.findall(r'<img[^>]*\ssrc="([^"]+)"', page.read_text(encoding="utf-8"))
        pngs = [src for src in sources if src.endswith(".png")]
        assert pngs, f"{name}: the page embeds no PNG figure"
        for src in pngs:
            image = (page.parent / src).resolve()
            assert image.is_file(), f"{name}: missing image {src}"
            assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{name}: {src} is not a PNG"


def test_intro_quotes_the_design_numbers_computed_by_the_figure_1_notebook(quick_book):
    from softpend.study.rod_design import rod_design

    _, _, html_dir = quick_book
    text = re.sub(r"<[^>]+>", "", (html_dir / "book" / "intro.html").read_text(encoding="utf-8"))
    design = rod_design()
    assert f"{design.tip_sag_horizontal_m * 1e3:.0f} mm" in text
    assert f"{100 * design.tip_sag_fraction:.0f} %" in text
    assert f"{design.torque_ratio:.2f}" in text
    figure_1 = (html_dir / "book" / "_generated" / "fig01_prb_rod.html").read_text(encoding="utf-8")
    assert "<table" in figure_1 and "buckling load factor" in figure_1  # the design table renders as a table


#: Notebooks that simulate nothing (the reward function): they need no ``plant`` parameter.
NO_PLANT = {"fig02_reward"}


def test_every_simulating_notebook_takes_a_plant_parameter(tmp_path):
    """Issue 8: the figure set is regenerated on the beam by one parameter (``softpend book --set plant=beam``)."""
    import papermill

    for name in toc_notebooks(REPO_ROOT / "_toc.yml"):
        if name in NO_PLANT:
            continue
        nb = book.read_notebook(REPO_ROOT / "notebooks" / f"{name}.md")
        path = tmp_path / f"{name}.ipynb"
        nbformat.write(nb, str(path))
        assert "plant" in papermill.inspect_notebook(str(path)), f"{name} has no `plant` parameter"
        defaults = {row["name"]: row["default"] for row in book.notebook_parameters(book._parameters_cell(nb))}
        assert defaults["plant"] in ("prb", "beam"), name
