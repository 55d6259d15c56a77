"""Text from others' files in the tables the zoo writes (``results.md``, ``aggregate.md``, ``diagnostics.md``): shown
as text, never as markup. Names and splits are checked before they reach a table (:mod:`sgfd_zoo.runs.fields`);
this escapes what a renderer would act on besides, so a cell cannot hold a link, an image, HTML or a line break.
"""

from __future__ import annotations

import re

from sgfd_zoo.arguments import printable

#: What CommonMark and GitHub's tables act on: HTML (``<``, ``>``, ``&``), links and images (``[``, ``]``, ``!``),
#: code, emphasis, headings, strike-through, and the cell separator ``|``.
MARKUP = re.compile(r"[\\`*\[\]<>&!#~|]")


def markdown_text(value: object, pipes: bool = True) -> str:
    """``value`` as text in a markdown table: control characters escaped (:func:`~sgfd_zoo.arguments.printable`),
    then every markup character backslash-escaped.

    :param value: a name, a split, a heading's text
    :param pipes: escape ``|`` too (False for pytablewriter's cells, which it escapes itself)
    """

    def escape(match: re.Match) -> str:
        return match.group() if match.group() == "|" and not pipes else "\\" + match.group()

    return MARKUP.sub(escape, printable(str(value)))
