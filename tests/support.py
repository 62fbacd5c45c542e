"""Helpers shared by several test modules (imported as ``from support import ...``; pytest puts this folder
on ``sys.path``)."""


def one_line_error(capsys, *words: str) -> str:
    """The captured stderr, asserted to be one line without a traceback that contains every word."""
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, err
    return err


#: The front matter of a jupytext MyST notebook, with ``{extra}`` for more front-matter lines.
NOTEBOOK_HEADER = """\
---
jupytext:
  text_representation:
    extension: .md
    format_name: myst
kernelspec:
  display_name: Python 3
  language: python
  name: python3
{extra}---
"""
