"""The comparison report: CNN vs baseline tables from measured numbers, detection variants."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.dataset import load_dataset
from service.core.paths import ASSETS_DIR, DEFAULT_MODEL
from service.pipeline.model import PoseModel
from train.cli import app
from train.compare.detection import detection_variants
from train.compare.run import camera_focal
from train.compare.sets import encode_png, same_object
from train.markdown import pct_cell
from train.network.evaluate import evaluate_predictor, model_predictor, onnx_predictor
from train.real.calibration import Calibration
from train.real.realset import build_real_dataset

SOURCE = ASSETS_DIR / "real" / "chessboard-stereo"
MODEL = DEFAULT_MODEL
NAME = MODEL.stem  # the model's name in the comparison: its card's
runner = CliRunner()


@pytest.fixture(scope="module")
def real_sets(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("cmp")
    _, wh, _ = onnx_predictor(MODEL)
    size = 1 if tuple(wh) == (80, 60) else 2  # the sets of the shipped model's input size
    sets = []
    for blur in (0, 3):
        out = root / f"real-s{size}-b{blur}"
        build_real_dataset(SOURCE, out, size=size, blur=blur, profile="chessboard", seed=0)
        sets.append(out)
    return sets


@pytest.fixture(scope="module")
def report(real_sets, tmp_path_factory) -> Path:
    md = tmp_path_factory.mktemp("doc") / "comparison.md"
    args = ["compare", "--models", str(MODEL), "--out", str(md), "--photos", str(SOURCE)]
    for ds in real_sets:
        args += ["--datasets", str(ds)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return md


def test_report_tables_hold_the_measured_numbers(report, real_sets):
    text = report.read_text()
    metrics = json.loads((report.with_suffix("") / "metrics.json").read_text())["results"]
    assert set(metrics) == {
        NAME, f"{NAME} + fx", "baseline-sift", "opencv-chessboard", "opencv-chessboard@stored"
    }  # fmt: skip
    for ds in real_sets:
        for name in (NAME, "baseline-sift", "opencv-chessboard"):
            cell = metrics[name][f"chessboard/{ds.name}"]
            assert {"accuracy", "per_class_accuracy", "confusion", "ms_per_image"} <= set(cell)
            assert f"{100 * cell['accuracy']:.1f}" in text
        assert cell["count"] == 6  # the real test split
    assert "## Real photographs per blur level" in text
    w, h = json.loads((real_sets[0] / "manifest.json").read_text())["size"]
    assert f"| {w}x{h} | 0 | 6 |" in text and f"| {w}x{h} | 3 | 6 |" in text
    for png in ("accuracy_vs_blur.png", "time_per_image.png"):
        assert (report.with_suffix("") / "plots" / png).is_file()
        assert f"]({report.stem}/plots/{png})" in text
    # the per-cell details go to the output folder's `details`, named but not linked
    details = report.with_suffix("") / "details"
    cell = f"## {NAME} on chessboard/{real_sets[0].name}"
    assert cell in (details / "details.md").read_text() and cell not in text
    assert (details / "plots" / f"{NAME}__chessboard_{real_sets[0].name}.png").is_file()
    assert f"`{(details / 'details.md').as_posix()}`" in text


def test_report_has_the_chessboard_peer_rows(report, real_sets):
    """The chessboard detector per size and blur level, its time ratio, the stored photos for
    reference and a sentence saying where each method is ahead."""
    text = report.read_text()
    metrics = json.loads((report.with_suffix("") / "metrics.json").read_text())["results"]
    peer = metrics["opencv-chessboard"]
    w, h = json.loads((real_sets[0] / "manifest.json").read_text())["size"]
    section = text.split("## The network vs the chessboard detector")[1].split("\n## ")[0]
    assert f"### real (chessboard-stereo), {w}x{h}" in section
    for ds, blur in zip(real_sets, (0, 3), strict=True):
        cell = peer[f"chessboard/{ds.name}"]
        assert cell["count"] == 6 and cell["ms_per_image"] > 0
        assert f"| {blur} | 6 | " in section
        assert f"{100 * cell['accuracy']:.1f} | " in section
    assert peer[f"chessboard/{real_sets[0].name}"]["accuracy"] >= 5 / 6  # sharp: found
    (stored,) = metrics["opencv-chessboard@stored"].values()
    assert stored["count"] == 6 and stored["accuracy"] == 1.0  # the photos as stored
    assert "stored photos, no blur (chessboard-stereo photos" in section
    assert f"At {w}x{h}, real (chessboard-stereo): the network (`{NAME}`) is ahead at" in section
    assert "detector / CNN time" in section and "The detector took" in section


def test_given_fx_is_the_model_given_the_detectors_focal_length(report, real_sets):
    """`default + fx`: the service's answer given each photo's calibrated fx (the source's
    calibration, in pixels of the network input), which changes the answer; its verdict."""
    metrics = json.loads((report.with_suffix("") / "metrics.json").read_text())["results"]
    model = PoseModel.load(MODEL)
    predict = model_predictor(model)
    for ds in real_sets:
        data = load_dataset(ds, split="test")
        cal = Calibration.load(SOURCE / "calibration.json")  # the source's calibration
        fx = [cal.for_image(Path(f).name, data.size).K[0, 0] for f in data.column("file")]
        focal = camera_focal(data, model.input_size[0])
        assert np.allclose(focal, np.array(fx) * model.input_size[0] / data.size[0])
        direct = evaluate_predictor(predict, data, focal=focal)
        assert metrics[f"{NAME} + fx"][f"chessboard/{ds.name}"]["confusion"] == direct["confusion"]
    images, aspect = data.images, data.pixel_aspect()
    assert not np.allclose(predict(images, aspect), predict(images, aspect, focal=focal * 3))
    text = report.read_text()
    assert f"* `{NAME} + fx`: `{NAME}` given each image's focal length fx" in text
    assert "Given the detector's focal length, at " in text
    assert f"the network (`{NAME} + fx`) is ahead at" in text


def test_report_breaks_the_real_photos_down_by_the_cameras_margin(report):
    text = report.read_text()
    metrics = json.loads((report.with_suffix("") / "metrics.json").read_text())["results"]
    section = text.split("## Real photographs by the camera's distance")[1].split("\n## ")[0]
    assert "| 0-2 cm % (n) | 2-5 cm % (n) | 5-10 cm % (n) | >= 10 cm % (n) |" in section
    for name in (NAME, "opencv-chessboard"):
        bands = next(iter(metrics[name].values()))["by_margin"]
        assert sum(b["count"] for b in bands) == 6  # every test photo shows the board
        cells = " | ".join(f"{pct_cell(b['accuracy'])} ({b['count']})" for b in bands)
        assert f"| {name} | {cells} |" in section


def test_detection_variants_are_reported(report):
    detections = json.loads((report.with_suffix("") / "detection_metrics.json").read_text())
    subsets = detections[NAME]
    counts = {"chessboard-stereo photos, all": 26, "chessboard-stereo photos, test split": 6}
    assert set(subsets) == set(counts)
    for name, per_variant in subsets.items():
        assert set(per_variant) == {"whole", "sliding", "proposals@1.5x", "proposals@4x"}
        assert all(m["count"] == counts[name] for m in per_variant.values())
    assert "proposals@4x" in report.read_text()


def test_whole_mode_matches_the_evaluator(real_sets):
    """The service's whole mode on PNG bytes finds the object where `evaluate` (the graph's
    own class) does, and answers within a few images of it: its class is its pose's region
    (docs/pose.md), from the same corners."""
    data = load_dataset(real_sets[0])
    predict, _, _ = onnx_predictor(MODEL)
    direct = evaluate_predictor(predict, data)
    via_service = detection_variants(MODEL, encode_png(data.images), data.labels)["all"]["whole"]
    service, graph = np.array(via_service["confusion"]), np.array(direct["confusion"])
    assert (service[:, 0] == graph[:, 0]).all() and (service[0] == graph[0]).all()
    assert abs(via_service["accuracy"] - direct["accuracy"]) <= 0.1


def test_no_given_fx_leaves_the_variant_out(real_sets, tmp_path):
    md = tmp_path / "c.md"
    args = ["compare", "--models", str(MODEL), "--datasets", str(real_sets[0]), "--out", str(md)]
    result = runner.invoke(app, [*args, "--peer", "chessboard", "--no-given-fx"])
    assert result.exit_code == 0, result.output
    metrics = json.loads((tmp_path / "c" / "metrics.json").read_text())["results"]
    assert NAME in metrics and f"{NAME} + fx" not in metrics


def test_cli_errors(real_sets, tmp_path):
    ds = ["--datasets", str(real_sets[0])]
    out = ["--out", str(tmp_path / "c.md")]
    result = runner.invoke(app, ["compare", "--models", str(tmp_path / "x.onnx"), *ds, *out])
    assert result.exit_code == 1 and "not an ONNX model" in result.output
    result = runner.invoke(app, ["compare", "--models", str(MODEL), "--datasets", str(tmp_path)])
    assert result.exit_code == 1 and "no labels.csv" in result.output
    args = ["compare", "--models", str(MODEL), *ds, *out, "--features", "surf"]
    assert runner.invoke(app, args).exit_code == 2
    result = runner.invoke(app, ["compare", "--models", str(MODEL), *ds, *out, "--peer", "hog"])
    assert result.exit_code == 2 and "--peer must be one of" in result.output
    args = ["compare", "--models", str(MODEL), *ds, *out, "--peer", "orb", "--features", "orb"]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "either --peer or --features" in result.output


def test_resize_runs_a_model_on_the_data_sets_of_another_size(tmp_path):
    """--resize: the default (160x120) also answers an 80x60 set, as the service answers an
    80x60 upload, and the report says so; without it the set is the detector's alone."""
    small = tmp_path / "real-s1-b0"
    build_real_dataset(SOURCE, small, size=1, blur=0, profile="chessboard", seed=0)
    data = load_dataset(small, split="test")
    predict, _, _ = onnx_predictor(MODEL)
    direct = evaluate_predictor(predict, data)
    results, texts = {}, {}
    for flag in ("--resize", "--no-resize"):
        md = tmp_path / flag / "comparison.md"
        args = ["compare", "--models", str(MODEL), "--datasets", str(small), "--out", str(md)]
        result = runner.invoke(app, [*args, "--peer", "chessboard", flag])
        assert result.exit_code == 0, result.output
        results[flag] = json.loads((md.with_suffix("") / "metrics.json").read_text())["results"]
        texts[flag] = md.read_text()
    resized = results["--resize"][NAME]["chessboard/real-s1-b0"]
    assert resized["count"] == 6 and resized["confusion"] == direct["confusion"]
    assert results["--no-resize"][NAME] == {}  # no set of its size
    assert "of its input size and its object only" in texts["--no-resize"]
    assert "resized to its input" in texts["--resize"]


def test_the_same_object_is_its_name_or_its_texture_and_size(tmp_path: Path) -> None:
    """A model is compared on its object's data sets: another profile name is another object
    unless the texture and the size are the same (the object seen by another camera)."""
    book = {"name": "book", "texture": "t/book.png", "width_cm": 15.0, "height_cm": 21.0}
    cases = [
        ({"name": "book"}, True),
        (book | {"name": "book-spec"}, True),
        (book | {"name": "poster", "texture": "t/poster.png"}, False),
        (book | {"name": "book-a5", "width_cm": 14.8}, False),
    ]
    for i, (profile, same) in enumerate(cases):
        folder = tmp_path / str(i)
        folder.mkdir()
        (folder / "manifest.json").write_text(json.dumps({"profile": profile}))
        assert same_object({"profile": book}, folder) is same, profile
