"""MkDocs hook: the docstrings use Sphinx roles (:class:`X`); drop the role so the name reads as code."""

from __future__ import annotations

import re
from typing import Any

_ROLE = re.compile(r":(?:attr|class|data|exc|func|meth|mod|obj|py:\w+):(?=<code>)")


def on_page_content(html: str, **kwargs: Any) -> str:
    """The page's HTML with every Sphinx role prefix before a code span removed."""
    return _ROLE.sub("", html)
