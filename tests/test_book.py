"""Build the whole book with the quick profile, in a temporary copy of the project (so neither `_build` nor
`book/_generated` of the working tree is touched), and check the HTML it produces."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import nbformat
import pytest

from softpend.study import book
from softpend.study.book import build_html, load_profiles, run_notebooks, toc_notebooks

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def quick_book(tmp_path_factory):
    """Copy the book sources, execute every toc notebook with the quick profile, build the HTML."""
    # others edit the package while the tests run: hash each notebook's code once, so the cache check below
    # is stable
    hash_code = book.PackageCode.code_hashes
    hashes: dict[tuple[str, ...], dict[str, str]] = {}

    def code_hashes_once(self, cells):
        cells = tuple(cells)
        if cells not in hashes:
            hashes[cells] = hash_code(self, cells)
        return hashes[cells]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(book.PackageCode, "code_hashes", code_hashes_once)
        yield _build_quick_book(tmp_path_factory.mktemp("book"))


def _build_quick_book(root: Path):
    for name in ("_config.yml", "_toc.yml"):
        shutil.copy2(REPO_ROOT / name, root / name)
    shutil.copytree(REPO_ROOT / "book", root / "book", ignore=shutil.ignore_patterns("_generated"))
    shutil.copytree(REPO_ROOT / "notebooks", root / "notebooks", ignore=shutil.ignore_patterns(".ipynb_checkpoints"))
    runs = run_notebooks(root, profile="quick", progress=False)
    html_dir = build_html(root, quiet=True)
    return root, runs, html_dir


def test_every_toc_notebook_has_a_quick_profile_and_executes_cleanly(quick_book):
    root, runs, _ = quick_book
    names = toc_notebooks(root / "_toc.yml")
    assert names, "the toc lists no notebooks"
    assert [run.name for run in runs] == names
    assert all(run.status == "executed" for run in runs)
    quick = load_profiles(root / "book" / "profiles.yml")["quick"]
    assert sorted(quick) == sorted(names), "every notebook needs a block in the quick profile"
    for run in runs:
        nb = nbformat.read(str(run.output_path), as_version=4)
        errors = [out for cell in nb.cells for out in cell.get("outputs", []) if out.output_type == "error"]
        assert not errors, f"{run.name}: {errors}"
    # a second run is served by the execution cache
    assert {run.status for run in run_notebooks(root, profile="quick", progress=False)} == {"cached"}


def test_html_pages_exist_and_embed_png_figures(quick_book):
    root, _, html_dir = quick_book
    assert html_dir == root.resolve() / "_build" / "html"
    assert (html_dir / "index.html").is_file()
    assert (html_dir / "book" / "intro.html").is_file()
    for name in toc_notebooks(root / "_toc.yml"):
        page = html_dir / "book" / "_generated" / f"{name}.html"
        assert page.is_file(), f"no HTML page for {name}"
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
        path = tmp_path / f"{name}.ipynb"
        nbformat.write(book.read_notebook(REPO_ROOT / "notebooks" / f"{name}.md"), str(path))
        declared = papermill.inspect_notebook(str(path))
        assert "plant" in declared, f"{name} has no `plant` parameter"
        assert declared["plant"]["default"].strip("'\"") in ("prb", "beam"), name
