"""Markdown pieces shared by the report writers: one table helper, one percent formatter."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any


def pct(value: float | None, digits: int = 1) -> str:
    """A fraction in [0, 1] as a percentage ("75.8 %"); "n/a" for None."""
    return "n/a" if value is None else f"{100 * value:.{digits}f} %"


def table(header: Sequence[Any], rows: Sequence[Sequence[Any]]) -> list[str]:
    """A Markdown table (list of lines) with a header row; cells are str()-ed, pipes escaped."""

    def line(cells: Sequence[Any]) -> str:
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    return [line(header), "|" + "---|" * len(header), *(line(r) for r in rows)]
