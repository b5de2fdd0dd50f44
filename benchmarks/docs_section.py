"""One section of docs/benchmarks.md, between its markers, rewritten by the benchmark that
measured it (the other sections stay as they are)."""

from __future__ import annotations

from pathlib import Path


def write_section(path: Path, key: str, title: str, body: list[str]) -> None:
    """Put `## title` and `body` between `<!-- key:start -->` and `<!-- key:end -->` in the
    markdown file `path`: in place of the old section, else appended (the file is created
    with a `# Benchmarks` title when missing)."""
    start, end = f"<!-- {key}:start -->", f"<!-- {key}:end -->"
    section = "\n".join([start, f"## {title}", "", *body, end])
    text = path.read_text(encoding="utf-8") if path.exists() else "# Benchmarks\n"
    if start in text and end in text:
        before, rest = text.split(start, 1)
        text = before + section + rest.split(end, 1)[1]
    else:
        text = text.rstrip("\n") + "\n\n" + section + "\n"
    path.write_text(text, encoding="utf-8")
