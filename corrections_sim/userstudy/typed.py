"""A person's own words shown as they typed them, never interpreted: a participant's free text
on their page and in the report, and what anyone typed into a page's box and is told back.

viser's Markdown renders HTML, so ``<b>was</b>`` showed bold and an ``<img onerror=…>`` would
run its script; Markdown's own marks (``*faster*``) would be read as emphasis.
"""

from __future__ import annotations

import re

#: Markdown's marks, each shown as itself when a backslash precedes it (CommonMark escapes any
#: ASCII punctuation; these are the ones that mean something).
_MARKS = re.compile(r"([\\`*_{}\[\]()#+\-.!|~>])")


def as_typed(text: object) -> str:
    """``text`` as Markdown that shows exactly its characters: HTML's ``&``, ``<`` and ``>``
    as entities (no tag, no script, no image is ever made of it), Markdown's marks escaped,
    and each line break a space (the text stays one line of a table or a list)."""
    flat = " ".join(str(text).splitlines())
    flat = flat.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _MARKS.sub(r"\\\1", flat)
