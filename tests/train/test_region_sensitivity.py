"""scripts/region_sensitivity.py: SPEC-camera renders come back exactly from their corners."""

from __future__ import annotations

import subprocess
import sys

from service.core.paths import REPO_ROOT
from service.core.profile import load_profile
from train.synth.generate import DatasetSpec, make_dataset

SCRIPT = REPO_ROOT / "scripts" / "region_sensitivity.py"


def test_exact_corners_of_renders_give_their_classes_and_noise_costs(tmp_path):
    data = tmp_path / "spec-s2-b0"
    make_dataset(data, DatasetSpec("noC", 2, 0, 60, 5, load_profile("chessboard-spec")))
    out = tmp_path / "page.md"
    run = [sys.executable, str(SCRIPT), str(data), "--split", "all", "--out", str(out)]
    done = subprocess.run(run, capture_output=True, text=True, cwd=REPO_ROOT, check=True)
    page = out.read_text()
    assert page.rstrip() == done.stdout.rstrip() and "do not edit by hand" in page
    rows = {line.split(" | ")[0].lstrip("| "): line for line in page.splitlines()}
    assert rows["exact"].rstrip(" |").endswith("100.0")  # the renderer's own camera, no lens
    noisy = float(rows["+ 1 px noise"].rstrip(" |").split(" | ")[-1])
    assert noisy < 100.0
    missing = subprocess.run(
        [sys.executable, str(SCRIPT), str(tmp_path / "nope")], capture_output=True, text=True
    )
    assert missing.returncode == 1 and "data set folder not found" in missing.stderr
