"""train.markdown.written_by: the line that dates a measured page."""

from __future__ import annotations

import os
import platform
import re

from train.markdown import written_by


def test_the_written_line_names_the_time_machine_and_command() -> None:
    line = written_by("python scripts/known_focal.py m.onnx data")
    assert re.match(r"Written \d{4}-\d\d-\d\d \d\d:\d\d UTC on ", line)
    assert f" on {platform.node()} (" in line and f", {os.cpu_count()} CPUs)" in line
    assert line.endswith("by `python scripts/known_focal.py m.onnx data`; do not edit by hand.")
