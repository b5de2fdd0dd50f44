"""What every test shares: onnxruntime logs errors only; the service's camera store in a
temporary folder, never the user's; under pytest-xdist (scripts/test.sh) the cores shared out
between the workers, and the longest test files first; in-process apps write no optimized
graphs in the background (`POSE_MODEL_PREPARE`: the many short-lived apps would each optimize
every shipped model; `test_service_model_cache.py` turns it on, and server processes get a
clean environment), and all of them, servers too, share one folder of optimized graphs.

The corner graphs' optional inputs are overridable initializers (`service.core.onnx_contract`),
about which onnxruntime warns at every load; the service sets the same level per session.
"""

import os
import tempfile
from pathlib import Path

import onnxruntime as ort
import pytest

from service.core.paths import DEFAULT_MODEL
from service.pipeline.model import PoseModel
from service.pipeline.model_cache import optimized_path

ort.set_default_logger_severity(3)
os.environ["POSE_MODEL_PREPARE"] = "false"
os.environ["POSE_CAMERA_DB"] = str(Path(tempfile.mkdtemp(prefix="pose-cameras-")) / "cameras.db")
# One folder of optimized graphs for the whole run (made by the first process, inherited by
# pytest-xdist's workers and passed to the servers the tests start): each graph is optimized
# once, not once per app and server. The default model's is written first, so that every app
# answers from that one graph from its first request (an app whose graph is swapped for the
# optimized one midway answers ~1e-5 differently: a proposals window can flip).
if "POSE_OPTIMIZED_DIR" not in os.environ:
    _optimized = Path(tempfile.mkdtemp(prefix="pose-optimized-"))
    os.environ["POSE_OPTIMIZED_DIR"] = str(_optimized)
    PoseModel.load(DEFAULT_MODEL, optimized=optimized_path(_optimized, DEFAULT_MODEL))

# Each xdist worker's torch and OpenCV thread pools get the worker's share of the cores (read
# when torch is first imported, after this file), not every core each.
WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if WORKERS > 1:
    for variable in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(variable, str(max(1, (os.cpu_count() or 1) // WORKERS)))

#: The test files that take longest (`--durations=0` summed per file: 13-48 s idle), run first
#: so that no worker starts one of them when the others have nothing left to do.
LONG_FIRST = (
    "test_service_shutdown.py",
    "test_compare.py",
    "test_container.py",
    "test_object_path.py",
    "test_corners.py",
    "test_docker_recipe.py",
    "test_object_train.py",
    "test_fit.py",
    "test_live_browser.py",
    "test_live_stream.py",
    "test_live_client.py",
    "test_cli_data.py",
    "test_service_workers.py",
    "test_generate.py",
)


@pytest.fixture(scope="session")
def default_model() -> PoseModel:
    """The default model, loaded from the run's optimized graph (written above)."""
    folder = Path(os.environ["POSE_OPTIMIZED_DIR"])
    return PoseModel.load(DEFAULT_MODEL, optimized=optimized_path(folder, DEFAULT_MODEL))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """`LONG_FIRST`'s files first, in its order; every other test after them, in the order
    collected (a file's tests stay together: `--dist loadfile`)."""
    rank = {name: i for i, name in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
