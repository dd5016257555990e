"""Docstrings as a terminal shows them (the help of the ``taiji2`` verbs)."""

from __future__ import annotations

import re

__all__ = ["plain_text"]

_ROLE = re.compile(r":(?:py:)?(?:mod|func|class|meth|attr|data|obj|exc):`~?([^`]+)`")


def plain_text(doc: str) -> str:
    """A docstring as a terminal shows it: reStructuredText markup (``code``, roles, ``::``) removed."""
    text = _ROLE.sub(lambda m: m.group(1), doc)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    text = re.sub(r"(?<=\S)::$", ":", text, flags=re.MULTILINE)
    return re.sub(r"^\s*::$\n?", "", text, flags=re.MULTILINE)
