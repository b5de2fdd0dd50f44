"""SPEC 10 metrics on hand-made confusions (exact values) and the report writer."""

from __future__ import annotations

import csv
import json
import platform
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from service.core.paths import ASSETS_DIR
from train.cli import app
from train.network.evaluate import (
    compute_metrics,
    confusion_matrix,
    predict_all,
    source_breakdown,
)
from train.network.report import framing_line, margin_line, write_report

runner = CliRunner()


def test_metrics_of_a_hand_made_confusion():
    # class 0: 4 images, 3 right, 1 called 5; class 1: 2 images, both called 5;
    # class 5: 3 images, all right; class 2: never seen, predicted once (from class 7).
    y_true = [0, 0, 0, 0, 1, 1, 5, 5, 5, 7]
    y_pred = [0, 0, 0, 5, 5, 5, 5, 5, 5, 2]
    m = compute_metrics(np.array(y_true), np.array(y_pred), ms_per_image=1.5)
    assert m["count"] == 10
    assert m["accuracy"] == pytest.approx(0.6)
    cm = np.array(m["confusion"])
    assert cm[0, 0] == 3 and cm[0, 5] == 1 and cm[1, 5] == 2 and cm[7, 2] == 1
    assert cm.sum() == 10
    assert m["per_class_accuracy"][0] == pytest.approx(0.75)
    assert m["per_class_accuracy"][1] == 0.0
    assert m["per_class_accuracy"][3] is None  # class 3 absent from the ground truth
    assert m["recall"] == m["per_class_accuracy"]
    assert m["precision"][0] == 1.0
    assert m["precision"][5] == pytest.approx(0.5)  # 3 right of 6 predicted
    assert m["precision"][2] == 0.0
    assert m["precision"][3] is None  # never predicted
    assert m["f1"][0] == pytest.approx(2 * 0.75 / 1.75)
    assert m["f1"][5] == pytest.approx(2 * 0.5 * 1.0 / 1.5)
    assert m["f1"][1] == 0.0
    assert m["f1"][2] == 0.0  # predicted once, never true
    assert m["f1"][3] is None  # neither true nor predicted
    assert m["ms_per_image"] == 1.5


def test_perfect_predictions():
    y = np.arange(9).repeat(3)
    m = compute_metrics(y, y, 0.1)
    assert m["accuracy"] == 1.0
    assert m["f1"] == [1.0] * 9
    assert np.array_equal(np.array(m["confusion"]), 3 * np.eye(9, dtype=int))


def test_region_breakdown_of_object_images():
    # Truth: 1 (near x+ y+) four times, 7 (far x- y-) twice, 0 once. Predictions: 1 right,
    # 5 (far x+ y+: side right, distance wrong), 3 (near x- y-: half turn, distance right),
    # 0 (missed), 7 right, 4 (near x+ y-: adjacent side, distance wrong); 0 -> 2 is ignored.
    y_true = np.array([1, 1, 1, 1, 7, 7, 0])
    y_pred = np.array([1, 5, 3, 0, 7, 4, 2])
    regions = compute_metrics(y_true, y_pred, 1.0)["regions"]
    assert regions == pytest.approx(
        {"detected": 5 / 6, "side": 3 / 6, "distance": 3 / 6, "opposite_side": 1 / 6}
    )
    none_shown = compute_metrics(np.zeros(3, int), np.array([0, 1, 0]), 1.0)["regions"]
    assert none_shown == dict.fromkeys(("detected", "side", "distance", "opposite_side"))


def test_accuracy_by_the_cameras_margin_from_a_region_boundary():
    y_true = np.array([1, 1, 2, 5, 6, 0])
    y_pred = np.array([1, 2, 2, 5, 6, 0])
    margin = np.array([0.5, 1.5, 3.0, 12.0, 40.0, np.nan])  # class 0 has no camera centre
    bands = compute_metrics(y_true, y_pred, 1.0, margin)["by_margin"]
    assert [(b["lo_cm"], b["hi_cm"], b["count"]) for b in bands] == [
        (0, 2, 2), (2, 5, 1), (5, 10, 0), (10, None, 2)
    ]  # fmt: skip
    assert [b["accuracy"] for b in bands] == [0.5, 1.0, None, 1.0]
    assert margin_line(bands).startswith(
        "Right class by the camera centre's distance from the nearest region boundary: "
        "0-2 cm: 50.0 % of 2, 2-5 cm: 100.0 % of 1, 5-10 cm: - % of 0, >= 10 cm: 100.0 % of 2"
    )
    assert "by_margin" not in compute_metrics(y_true, y_pred, 1.0)


def test_accuracy_on_boards_the_frame_cuts_and_on_whole_ones():
    y_true = np.array([1, 1, 2, 5, 0])
    y_pred = np.array([1, 2, 2, 6, 0])
    cut = np.array([0.0, 1.0, 1.0, 1.0, np.nan])  # class 0 has no corners
    framing = compute_metrics(y_true, y_pred, 1.0, cut=cut)["by_framing"]
    assert framing == {
        "whole": {"count": 1, "accuracy": 1.0}, "cut": {"count": 3, "accuracy": 1 / 3}
    }  # fmt: skip
    assert framing_line(framing) == (
        "Boards the frame cuts (a labelled corner outside the image): 33.3 % of 3; "
        "whole in view: 100.0 % of 1."
    )
    none_cut = compute_metrics(y_true, y_pred, 1.0, cut=np.where(cut > 0, 0.0, cut))
    assert framing_line(none_cut["by_framing"]) == ""
    assert "by_framing" not in compute_metrics(y_true, y_pred, 1.0)


def test_breakdown_by_source_with_its_cameras_focal_length():
    # camera a: 3 board photos (one far called near, one x side wrong); b: 2 negatives, one missed
    y_true = np.array([5, 1, 2, 0, 0])
    y_pred = np.array([1, 1, 1, 0, 3])
    rows = [
        {"source": "a", "focal_scale": "1.7"},
        {"source": "a", "focal_scale": "1.9"},
        {"source": "a", "focal_scale": ""},  # no calibration: left out of the median
        {"source": "b", "focal_scale": ""},
        {"source": "b", "focal_scale": ""},
    ]
    out = source_breakdown(y_true, y_pred, rows)
    assert list(out) == ["a", "b"]
    expected = {"count": 3, "accuracy": 1 / 3, "detected": 1.0, "side": 2 / 3, "distance": 2 / 3}
    assert out["a"] == pytest.approx(expected | {"focal_scale": 1.8}, abs=1e-4)  # 4 digits
    assert out["b"]["count"] == 2 and out["b"]["accuracy"] == 0.5
    assert out["b"]["side"] is None and out["b"]["focal_scale"] is None
    assert source_breakdown(y_true, y_pred, [{} for _ in rows]) == {}  # renders: no source


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="2 labels but 3 predictions"):
        confusion_matrix(np.array([0, 1]), np.array([0, 1, 2]))
    with pytest.raises(ValueError, match="0..8"):
        confusion_matrix(np.array([0, 9]), np.array([0, 1]))
    with pytest.raises(ValueError, match="no samples"):
        compute_metrics(np.array([], int), np.array([], int), 0.0)


def test_predict_all_batches_and_times():
    calls, aspects = [], []

    def predict(images, pixel_aspect):
        calls.append(len(images))
        aspects.append(pixel_aspect)
        p = np.zeros((len(images), 9), np.float32)
        p[:, 4] = 1
        return p

    probs, ms = predict_all(predict, np.zeros((70, 6, 8, 3), np.uint8), batch=32)
    assert calls == [32, 32, 6] and all((a == 1).all() for a in aspects)
    assert probs.shape == (70, 9) and (probs.argmax(1) == 4).all()
    assert ms >= 0
    aspect = np.linspace(0.75, 1.5, 70, dtype=np.float32)
    aspects.clear()
    predict_all(predict, np.zeros((70, 6, 8, 3), np.uint8), aspect, batch=32)
    assert np.array_equal(np.concatenate(aspects), aspect)


def test_report_writes_json_markdown_and_plots(tmp_path):
    rng = np.random.default_rng(0)
    y = rng.integers(0, 9, 50)
    results = {
        "net-a": {"set1": compute_metrics(y, y, 1.0), "set2": compute_metrics(y, y[::-1], 2.0)},
        "net-b": {"set1": compute_metrics(y, np.zeros_like(y), 0.5)},
    }
    out = tmp_path / "out"
    md = write_report(results, out, tmp_path / "docs" / "results.md", "T", ["hi"])
    doc = json.loads((out / "metrics.json").read_text())
    assert doc["results"]["net-a"]["set1"]["accuracy"] == 1.0
    assert len(doc["results"]["net-a"]["set2"]["confusion"]) == 9
    assert doc["date"] and f"{platform.node()} (" in doc["machine"]
    # the page: the summary tables and the grid's plot, no per-cell section
    text = md.read_text()
    assert "| net-a | 100.0 |" in text
    assert "## Right x/y side (%)" in text and "## Right near/far (%)" in text
    assert "](../out/plots/grid.png)" in text and "](../out/metrics.json)" in text
    assert "## net-a on set1" not in text and f"`{out / 'details' / 'details.md'}`" in text
    assert [p.name for p in (out / "plots").glob("*.png")] == ["grid.png"]
    # the details, in the output folder: one section and one plot per cell
    details = (out / "details" / "details.md").read_text()
    assert "## net-a on set1" in details and "x/y side right 100.0 %" in details
    assert "](plots/net-b__set1.png)" in details
    pngs = sorted(p.name for p in (out / "details" / "plots").glob("*.png"))
    assert pngs == ["net-a__set1.png", "net-a__set2.png", "net-b__set1.png"]


@pytest.fixture(scope="module")
def model_and_set(tmp_path_factory):
    """A tiny exported model (random weights) and the real photos as an 80x60 data set."""
    import torch

    from train.network.export import export
    from train.network.fit import CHECKPOINT_FORMAT
    from train.network.model import PoseNet
    from train.real.realset import build_real_dataset

    root = tmp_path_factory.mktemp("eval")
    source = ASSETS_DIR / "real" / "chessboard-stereo"
    build_real_dataset(source, root / "real", size=1, blur=0, profile="chessboard", seed=0)
    torch.manual_seed(0)
    ckpt = {
        "format": CHECKPOINT_FORMAT,
        "size": [80, 60],
        "model": PoseNet((80, 60)).state_dict(),
        "config": {"seed": 0},
    }
    torch.save(ckpt, root / "best.pt")
    onnx_path, _ = export(root / "best.pt", "tiny", root)
    return onnx_path, root / "best.pt", root / "real"


def _with_sources(data: Path, out: Path) -> Path:
    """A copy of a data set whose photos name their camera (`source`), as the corpus's do."""
    shutil.copytree(data, out)
    with (data / "labels.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    with (out / "labels.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, [*rows[0], "source"])
        writer.writeheader()
        for row in rows:
            writer.writerow(row | {"source": "left" if "left" in row["file"] else "right"})
    return out


def test_cli_evaluates_onnx_and_checkpoint_the_same(model_and_set, tmp_path):
    onnx_path, ckpt, data = model_and_set
    data = _with_sources(data, tmp_path / "real")
    out = tmp_path / "out"
    args = ["evaluate", str(onnx_path), str(ckpt), str(data), "--out", str(out), "--split", "all"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    doc = json.loads((out / "metrics.json").read_text())
    onnx_m = doc["results"]["tiny"]["real"]
    torch_m = doc["results"][ckpt.parent.name]["real"]
    assert onnx_m["count"] == 26
    # the OpenCV pair's cameras: margins from their labelled centres, all photos show the board
    assert sum(b["count"] for b in onnx_m["by_margin"]) == 26
    assert onnx_m["confusion"] == torch_m["confusion"]
    assert sum(map(sum, onnx_m["confusion"])) == 26
    # a real set: the breakdown by source (camera), in metrics.json and in the report
    assert list(onnx_m["by_source"]) == ["left", "right"]
    assert sum(v["count"] for v in onnx_m["by_source"].values()) == 26
    assert onnx_m["by_source"] == torch_m["by_source"]
    assert "| tiny | " in (out / "report.md").read_text()
    details = (out / "details" / "details.md").read_text()
    assert "By source:" in details and "| source | photos | accuracy | detected |" in details
    for name, v in onnx_m["by_source"].items():
        assert f"| `{name}` | {v['count']} | {100 * v['accuracy']:.1f} % |" in details
    assert (out / "plots" / "grid.png").is_file()


def test_cli_evaluate_errors(model_and_set, tmp_path):
    onnx_path, _, data = model_and_set
    result = runner.invoke(app, ["evaluate", str(data), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "at least one model" in result.output
    result = runner.invoke(app, ["evaluate", str(onnx_path), "--out", str(tmp_path)])
    assert result.exit_code == 2 and "at least one data set" in result.output
    result = runner.invoke(app, ["evaluate", str(onnx_path), str(tmp_path), "--out", str(tmp_path)])
    assert result.exit_code == 1 and "not a data set" in result.output
    args = ["evaluate", str(tmp_path / "x.onnx"), str(data), "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 1 and "model not found" in result.output
    args = ["evaluate", str(onnx_path), str(data), "--out", str(tmp_path), "--split", "nope"]
    assert runner.invoke(app, args).exit_code == 2
