"""The README is a front page: at most 100 lines, its figure exists, and its Python example runs and balances."""

from __future__ import annotations

import contextlib
import io
import math
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def test_the_readme_is_a_front_page():
    text = README.read_text()
    assert len(text.splitlines()) <= 100
    for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (ROOT / image).is_file(), image
    assert "make book" in text and "make test" in text and "CONTRIBUTING.md" in text
    # no build timings on the front page (they live on the execution page the build writes)
    assert not re.search(r"\d+ min \d+ s|wall \[s\]|CPU s\b", text)


def test_the_readme_example_runs_and_the_controller_balances():
    blocks = python_blocks(README.read_text())
    assert len(blocks) == 1, "the README has one Python example"
    namespace: dict = {"__name__": "readme_example"}
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        exec(compile(blocks[0], str(README), "exec"), namespace)
    env, summary = namespace["env"], namespace["summary"]
    assert env.observation_space.contains(namespace["observation"])
    assert math.isfinite(namespace["reward"])
    assert len(summary.results) == 3 and summary.successes == 3
    for result in summary.results:
        assert result.diverged is None and result.swing_up_time_s < 5.0 and result.upright_std_rad < 0.2
    assert printed.getvalue().startswith("3 of 3 starts balanced")
