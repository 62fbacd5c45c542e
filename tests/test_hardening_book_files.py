"""Malformed project files of the book: ``_toc.yml`` and ``book/profiles.yml`` that are not valid YAML, are YAML
of the wrong shape, or are not regular files give one line naming the file, the line and what was expected --
from ``softpend book`` and from ``softpend sweep --book`` alike -- never a parser traceback or a hang."""

from __future__ import annotations

import os

import pytest
from support import refused

from softpend.study.book import load_profiles, toc_notebooks

TOC = (
    "format: jb-book\nroot: book/intro\nparts:\n  - caption: Figures\n    chapters:\n"
    "      - file: book/_generated/fig02_reward\n"
)


@pytest.fixture
def root(tmp_path):
    (tmp_path / "book").mkdir()
    (tmp_path / "_toc.yml").write_text(TOC)
    (tmp_path / "book" / "profiles.yml").write_text("quick:\n  fig02_reward: {n_points: 3}\n")
    return tmp_path


PROFILES = [
    ("quick:\n  fig02_reward: {n_points: 3\n", r"line 3 column 1: not valid YAML \(expected ',' or '}'"),
    ("quick:\n  fig02_reward:\n    n_points: 3\n   bad: [\n", r"line \d+ column \d+: not valid YAML"),
    ("quick: [1, 2]\n", r"line 1: expected a mapping notebook -> parameters for profile 'quick', got list"),
    (
        "quick:\n  other: {}\n  fig02_reward: 5\n",
        r"line 3: expected a mapping parameter -> value for notebook "
        r"'fig02_reward' of profile 'quick', got int 5",
    ),
    ("- quick\n", r"line 1: expected a mapping profile -> notebook -> parameters, got list"),
    ("!!python/object/apply:os.system ['true']\n", r"line 1 column 1: not valid YAML"),
]


@pytest.mark.parametrize("text, message", PROFILES)
@pytest.mark.parametrize("command", [["book"], ["sweep", "--book"]])
def test_malformed_profiles(root, text, message, command):
    (root / "book" / "profiles.yml").write_text(text)
    line = refused([*command, "--root", str(root), "--profile", "quick"])
    assert str(root / "book" / "profiles.yml") in line
    assert __import__("re").search(message, line), line
    with pytest.raises(ValueError, match=message):
        load_profiles(root / "book" / "profiles.yml")


TOCS = [
    ("format: jb-book\nroot: [\n", r"line \d+ column \d+: not valid YAML"),
    ("just a sentence\n", r"line 1: expected a mapping with format, root and parts or chapters, got str"),
    ("format: jb-book\nparts: []\n", r"line 1: expected a 'root' entry"),
    (
        "format: jb-book\nroot: book/intro\nparts:\n  - caption: F\n    chapters: book/_generated/x\n",
        r"line 5: expected 'chapters' to be a list of entries, got str",
    ),
    (
        "format: jb-book\nroot: book/intro\nparts:\n  - caption: F\n    chapters:\n      - file: [1]\n",
        r"line 6: expected 'file' to be a string, got list",
    ),
    ("format: jb-book\nroot: book/intro\nparts:\n  - 5\n", r"line 4: expected each of 'parts' to be a mapping"),
]


@pytest.mark.parametrize("text, message", TOCS)
@pytest.mark.parametrize("command", [["book"], ["sweep", "--book"]])
def test_malformed_toc(root, text, message, command):
    (root / "_toc.yml").write_text(text)
    line = refused([*command, "--root", str(root), "--profile", "quick"])
    assert str(root / "_toc.yml") in line
    assert __import__("re").search(message, line), line
    with pytest.raises(ValueError, match=message):
        toc_notebooks(root / "_toc.yml")


@pytest.mark.timeout(120, method="thread")
@pytest.mark.parametrize("kind", ["fifo", "folder", "dev_zero"])
@pytest.mark.parametrize("command", [["book"], ["sweep", "--book"]])
def test_special_profiles_file(root, kind, command):
    path = root / "book" / "profiles.yml"
    path.unlink()
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    else:
        path.symlink_to("/dev/zero")
    line = refused([*command, "--root", str(root), "--profile", "quick"])
    assert "profiles.yml" in line


def test_the_project_files_pass(tmp_path):
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    assert toc_notebooks(repo / "_toc.yml")
    profiles = load_profiles(repo / "book" / "profiles.yml")
    assert "quick" in profiles and all(type(v) is dict for v in profiles.values())


@pytest.mark.timeout(120, method="thread")
def test_a_notebook_source_that_is_a_fifo(root):
    """``notebooks/NAME.md`` a named pipe: refused by name, not read until a writer appears."""
    (root / "notebooks").mkdir()
    os.mkfifo(root / "notebooks" / "fig02_reward.md")
    line = refused(["book", "--root", str(root), "--profile", "quick"])
    assert "fig02_reward.md" in line and "named pipe" in line


@pytest.mark.timeout(120, method="thread")
@pytest.mark.parametrize("command", [["book"], ["sweep", "--book"]])
def test_a_toc_that_is_a_fifo_is_named_as_such(root, command):
    """Before: ``_toc.yml`` a named pipe was reported as a missing ``_toc.yml``."""
    (root / "_toc.yml").unlink()
    os.mkfifo(root / "_toc.yml")
    line = refused([*command, "--root", str(root), "--profile", "quick"])
    assert "_toc.yml is not a regular file" in line
