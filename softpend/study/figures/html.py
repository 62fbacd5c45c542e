"""Figures as HTML that reads offline: matplotlib animations without the stylesheet it fetches from a CDN."""

from __future__ import annotations

import re
from typing import Any

#: The Font Awesome 4 stylesheet that matplotlib's JavaScript player links from a CDN (its button icons).
_CDN_STYLESHEET = re.compile(r'<link rel="stylesheet"\s+href="https://[^"]*font-awesome[^"]*">\s*')


def offline_jshtml(animation: Any, **kwargs: Any) -> str:
    """``animation.to_jshtml(**kwargs)`` without its CDN stylesheet link; ``ValueError`` unless there is one."""
    html = animation.to_jshtml(**kwargs)
    stripped, count = _CDN_STYLESHEET.subn("", html)
    if count != 1:
        raise ValueError(f"expected one CDN stylesheet link in the animation's HTML, found {count}")
    return stripped
