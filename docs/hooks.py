"""MkDocs hooks: the docstrings use Sphinx roles (:class:`X`), so the role is dropped and the name reads as code;
and a page may show a part of the README (``<!-- README: intro -->``), so the front page is written once."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

_ROLE = re.compile(r":(?:attr|class|data|exc|func|meth|mod|obj|py:\w+):(?=<code>)")
_README = Path(__file__).resolve().parents[1] / "README.md"
_INCLUDE = re.compile(r"^<!-- README: (\w+) -->$", flags=re.MULTILINE)


def readme_part(name: str, readme: str | None = None) -> str:
    """The README's text between ``<!-- name ... -->`` and ``<!-- /name -->``, its links into ``docs/`` made
    relative to the pages.

    :param name: the part's name
    :param readme: the README's text (default: the repository's README.md)
    """
    text = _README.read_text() if readme is None else readme
    match = re.search(rf"^<!-- {name}\b[^>]*-->\n(.*?)^<!-- /{name} -->$", text, flags=re.MULTILINE | re.DOTALL)
    if match is None:
        raise ValueError(f"name must be a part of README.md marked <!-- {name} --> ... <!-- /{name} -->, got {name!r}")
    return match.group(1).replace("](docs/", "](")


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    """The page's markdown with each ``<!-- README: name -->`` line replaced by that part of the README."""
    return _INCLUDE.sub(lambda found: readme_part(found.group(1)), markdown)


def on_page_content(html: str, **kwargs: Any) -> str:
    """The page's HTML with every Sphinx role prefix before a code span removed."""
    return _ROLE.sub("", html)
