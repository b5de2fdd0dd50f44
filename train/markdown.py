"""Markdown pieces shared by the report writers: a table helper, a percent formatter, the
"written on" line of a measured page."""

from __future__ import annotations

import os
import platform
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any


def pct(value: float | None, digits: int = 1, *, unit: bool = True, missing: str = "n/a") -> str:
    """A fraction in [0, 1] as a percentage ("75.8 %"; "75.8" with unit=False, for table
    columns whose header says %); `missing` for None."""
    if value is None:
        return missing
    return f"{100 * value:.{digits}f}" + (" %" if unit else "")


def pct_cell(value: float | None) -> str:
    """A percentage for a table column whose header says % ("75.8"); "-" for None."""
    return pct(value, unit=False, missing="-")


def table(header: Sequence[Any], rows: Sequence[Sequence[Any]]) -> list[str]:
    """A Markdown table (list of lines) with a header row; cells are str()-ed, pipes escaped."""

    def line(cells: Sequence[Any]) -> str:
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"

    return [line(header), "|" + "---|" * len(header), *(line(r) for r in rows)]


def link(path: Path, base: Path) -> str:
    """`path` relative to the folder `base` of the Markdown file that links it (POSIX)."""
    return Path(os.path.relpath(path, base)).as_posix()


def machine() -> str:
    """This machine as a measured page names it: host (CPU, CPU count), and how many of its
    CPUs this process may use when that is fewer (`taskset`, a container's cpuset)."""
    cpu = platform.processor() or platform.machine()
    count = os.cpu_count() or 0
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else count
    pinned = f", pinned to {usable} of them" if 0 < usable < count else ""
    return f"{platform.node()} ({cpu}, {count} CPUs){pinned}"


def written_by(command: str) -> str:
    """The line that dates a measured page: now (UTC), this machine (`machine`) and the
    `command` that wrote it."""
    stamp = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    return f"Written {stamp} on {machine()} by `{command}`; do not edit by hand."
