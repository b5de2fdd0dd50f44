"""planar-pose training side, one sub-package per pipeline step.

* `train.synth`: synthetic images of the object (render, blur, backgrounds, data sets);
* `train.real`: real photographs (corners, calibration, labelling, real data sets);
* `train.network`: the CNN (model, training loop, evaluation, export);
* `train.compare`: the feature baseline and the comparison report;
* `train.geometry`, `train.profile`, `train.dataset`: shared by all of them;
* `train/assets/`: the data files (profiles, backgrounds, real photographs).

Modules that need torch import it themselves; importing this package does not.
"""

from pathlib import Path

#: The package's data files: profiles/, backgrounds/, real/.
ASSETS_DIR = Path(__file__).resolve().parent / "assets"
REPO_ROOT = Path(__file__).resolve().parent.parent


def repo_relative(path: Path) -> str:
    """`path` relative to the repository root (POSIX) when inside it, else absolute."""
    try:
        return path.resolve().relative_to(REPO_ROOT).as_posix()
    except ValueError:
        return str(path.resolve())
