"""Sphinx extension of the book: each script of a page is included once.

sphinx-thebe registers its configuration script (``const THEBE_JS_URL = ...``) and sphinx-togglebutton its
selector each time Sphinx reads the sources, and Jupyter Book's build reads them twice, so every page
declared the same ``const`` twice: a JavaScript error on every page.  :func:`drop_duplicate_scripts` keeps
the first of identical scripts (same file or same inline body, same attributes).
"""

from __future__ import annotations

from typing import Any


def _script_key(script: Any) -> tuple:
    """What makes two scripts the same: the file (an inline script has ``None`` or ``""``) and attributes."""
    filename = getattr(script, "filename", script)
    attributes = tuple(sorted((str(k), str(v)) for k, v in getattr(script, "attributes", {}).items()))
    return (str(filename or ""), attributes)


def drop_duplicate_scripts(app, pagename: str, templatename: str, context: dict, doctree) -> None:
    """``html-page-context`` handler: remove repeated entries from the page's ``script_files``."""
    scripts = context.get("script_files")
    if not scripts:
        return
    seen, kept = set(), []
    for script in scripts:
        key = _script_key(script)
        if key not in seen:
            seen.add(key)
            kept.append(script)
    context["script_files"] = kept


def setup(app) -> dict:
    app.connect("html-page-context", drop_duplicate_scripts, priority=900)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
