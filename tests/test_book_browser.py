"""The quick book (session fixture ``quick_book``) read in headless Chromium, page by page, as a reader sees
it; and the same checks catching a page broken on purpose.  Screenshots are kept under the test's tmp dir."""

from __future__ import annotations

import shutil

from browser import book_pages, check_pages
from PIL import Image

from softpend.study.book import toc_notebooks


def test_every_page_of_the_quick_book_reads_clean_in_chromium(quick_book, chromium, tmp_path_factory):
    root, _, html_dir = quick_book
    pages = book_pages(html_dir)
    expected = {f"book/_generated/{name}.html" for name in toc_notebooks(root / "_toc.yml")}
    expected |= {"index.html", "book/intro.html", "book/_generated/execution.html"}
    assert expected <= set(pages), sorted(expected - set(pages))
    shots = tmp_path_factory.mktemp("screenshots")
    problems = check_pages(html_dir, pages, shots, executable=chromium)
    assert set(problems) == set(pages)
    for page in pages:  # one screenshot per page, a PNG of the page's width
        with Image.open(shots / (page.replace("/", "__") + ".png")) as shot:
            assert shot.format == "PNG" and shot.size[0] > 800, page
    broken = {page: found for page, found in problems.items() if found}
    assert not broken, f"screenshots in {shots}:\n" + "\n".join(
        f"{page}:\n  " + "\n  ".join(found[:20]) + (f"\n  ... {len(found) - 20} more" if len(found) > 20 else "")
        for page, found in broken.items()
    )


#: Injected into a real page of the book: one of each kind of problem the checks must find.
BROKEN = """
<section id="deliberately-broken">
  <img src="not-an-image.png" alt="broken">
  <a href="no-such-page.html">missing page</a>
  <a href="fig01_prb_rod.html#no-such-anchor">missing anchor</a>
  <a href="fig01_prb_rod.html">a good link</a>
  <div class="cell_output docutils container"><div class="output stderr highlight-myst-ansi notranslate">
    <div class="highlight"><pre>/tmp/x.py:1: UserWarning: something is off</pre></div></div></div>
  <div class="cell_output docutils container"><div class="output traceback highlight-ipythontb notranslate">
    <div class="highlight"><pre>Traceback (most recent call last):
ValueError: bad</pre></div></div></div>
  <p>The tip sags {glue:text}`tip_sag_mm:.0f` mm.</p>
  <script>window.setTimeout(() => { throw new Error("deliberate"); }, 0);</script>
</section>
"""


def test_the_checks_find_every_problem_of_a_deliberately_broken_page(quick_book, chromium, tmp_path):
    _, _, html_dir = quick_book
    copy = tmp_path / "html"
    shutil.copytree(html_dir, copy)
    (copy / "book" / "_generated" / "not-an-image.png").write_bytes(b"this is not a PNG")
    page = copy / "book" / "_generated" / "fig02_reward.html"
    text = page.read_text(encoding="utf-8")
    assert "</main>" in text
    page.write_text(text.replace("</main>", BROKEN + "</main>", 1), encoding="utf-8")
    problems = check_pages(copy, ["book/_generated/fig02_reward.html"], tmp_path / "shots", executable=chromium)[
        "book/_generated/fig02_reward.html"
    ]
    report = "\n".join(problems)

    def found(kind: str, *words: str) -> bool:
        return any(p.startswith(kind + ":") and all(w in p for w in words) for p in problems)

    assert found("image", "not-an-image.png"), report
    assert found("link", "no-such-page.html"), report
    assert found("link", "no-such-anchor"), report
    assert not found("link", "'fig01_prb_rod.html'"), report  # the good link passes
    assert found("console", "deliberate"), report
    assert found("output", "UserWarning"), report
    assert found("output", "Traceback"), report
    assert found("glue", "{glue:text}"), report
    assert (tmp_path / "shots" / "book___generated__fig02_reward.html.png").is_file()
