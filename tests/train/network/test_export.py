"""ONNX export: PyTorch vs onnxruntime parity, dynamic batch, the model card."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from service.core.paths import ASSETS_DIR, REPO_ROOT
from service.core.preprocess import to_network_input
from train.network.export import export
from train.network.fit import CHECKPOINT_FORMAT
from train.network.model import PoseNet
from train.real.realset import read_rgb

REAL = ASSETS_DIR / "real" / "chessboard-stereo"


def _checkpoint(
    tmp_path: Path, size: tuple[int, int], batch_norm: bool = False
) -> tuple[Path, PoseNet]:
    torch.manual_seed(1)
    net = PoseNet(size, batch_norm=batch_norm)
    net.set_normalisation(torch.tensor([0.4, 0.5, 0.6]), torch.tensor([0.2, 0.25, 0.3]))
    if batch_norm:  # running statistics of real-looking inputs instead of the identity
        with torch.no_grad():
            net.train()(torch.rand(16, 3, size[1], size[0]))
    path = tmp_path / "best.pt"
    torch.save(
        {
            "format": CHECKPOINT_FORMAT,
            "size": list(size),
            "batch_norm": batch_norm,
            "model": net.state_dict(),
            "config": {"seed": 7, "epochs": 3},
            "data": [{"path": "data/x", "split": "train", "count": 10, "blur": 0}],
            "profile": {"name": "test", "width_cm": 25.0, "height_cm": 17.5, "z_split_cm": 30.0},
            "epoch": 3,
            "best": {"epoch": 2, "val_accuracy": 0.5, "val_loss": 1.0},
        },
        path,
    )
    return path, net.eval()


@pytest.mark.parametrize(
    ("size", "batch_norm"), [((80, 60), False), ((160, 120), False), ((80, 60), True)]
)
def test_onnx_matches_pytorch_on_random_and_real_inputs(tmp_path, size, batch_norm):
    ckpt, net = _checkpoint(tmp_path, size, batch_norm)
    path, card = export(ckpt, "m", tmp_path / "models")
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert {"Conv", "Tanh", "AveragePool", "Sqrt", "Gemm", "Softmax"} <= ops
    assert "BatchNormalization" not in ops  # folded into the SPEC layers
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    photos = sorted(REAL.glob("*.jpg"))[:17]
    real = np.stack([to_network_input(read_rgb(p), size) for p in photos])
    for batch in (1, 17):
        random = rng.random((batch, 3, size[1], size[0]), dtype=np.float32)
        for x in (random, real[:batch]):
            got = session.run(["probabilities"], {"image": x})[0]
            with torch.no_grad():
                want = torch.softmax(net.logits(torch.from_numpy(x)), 1).numpy()
            assert got.shape == (batch, 9) and got.dtype == np.float32
            assert np.abs(got - want).max() < 1e-5
            np.testing.assert_allclose(got.sum(1), 1.0, atol=1e-5)


def test_card_is_in_the_metadata_and_beside_the_file(tmp_path):
    ckpt, _ = _checkpoint(tmp_path, (80, 60))
    path, card = export(ckpt, "tiny", tmp_path, version="0.3.0", notes="a test")
    model = onnx.load(str(path))
    onnx.checker.check_model(model)
    meta = {p.key: p.value for p in model.metadata_props}
    assert json.loads(meta["model_card"]) == card
    assert json.loads((tmp_path / "tiny.json").read_text()) == card
    assert card["name"] == "tiny" and card["version"] == "0.3.0" and card["notes"] == "a test"
    assert card["input"] == [80, 60]
    assert [c["id"] for c in card["classes"]] == list(range(9))
    assert card["classes"][7]["label"] == "far, x-, y-"
    assert "z >= 30 cm" in card["classes"][7]["description"]
    assert card["profile"]["z_split_cm"] == 30.0
    assert card["training"]["seed"] == 7
    graph_inputs = model.graph.input[0].type.tensor_type.shape.dim
    assert graph_inputs[0].dim_param == "N" and [d.dim_value for d in graph_inputs[1:]] == [
        3,
        60,
        80,
    ]
    assert model.graph.output[0].name == "probabilities"
    assert path.stat().st_size < 2_000_000


def test_a_shipped_model_is_measured_again(tmp_path):
    from train.network.export import recard
    from train.real.realset import build_real_dataset

    ckpt, _ = _checkpoint(tmp_path, (80, 60))
    path, card = export(ckpt, "tiny", tmp_path / "a", notes="first")
    real = tmp_path / "real-s1-b0"
    build_real_dataset(REAL, real, size=1, blur=0, profile="chessboard", seed=0)
    again, new = recard(path, "tiny2", tmp_path / "b", [real], split="all", val_datasets=[real])
    assert new["name"] == "tiny2" and new["notes"] == "first"
    assert new["training"] == card["training"] and new["input"] == card["input"]
    assert new["accuracy"]["real-s1-b0"]["count"] == 26
    val = new["accuracy_val"]["real-s1-b0"]  # its 6 val photos
    assert val["split"] == "val" and val["count"] == 6
    _, measured = recard(again, "tiny3", tmp_path / "c", [real], split="all")
    assert "accuracy_val" not in measured  # not measured again: not carried over
    meta = {p.key: p.value for p in onnx.load(str(again)).metadata_props}
    assert (
        json.loads(meta["model_card"]) == new == json.loads((tmp_path / "b/tiny2.json").read_text())
    )
    with pytest.raises(ValueError, match="no model card"):
        bare = tmp_path / "bare.onnx"
        model = onnx.load(str(path))
        del model.metadata_props[:]
        onnx.save(model, str(bare))
        recard(bare, "x", tmp_path, [real])


def test_catalog_lists_every_card_with_its_measured_accuracy(tmp_path):
    from train.network.catalog import write_catalog

    ckpt, _ = _checkpoint(tmp_path, (80, 60))
    models = tmp_path / "models"
    _, card = export(ckpt, "tiny", models, notes="how it was made")
    by_source = {
        "cam-a": {"count": 6, "accuracy": 1 / 3, "detected": 1.0, "side": 0.5,
                  "distance": 2 / 3, "focal_scale": 1.73},
        "negatives": {"count": 4, "accuracy": 0.0},  # a card from before the breakdown
    }  # fmt: skip
    card["accuracy"] = {
        "real-s1-b0": {"split": "test", "count": 10, "accuracy": 0.25, "by_source": by_source}
    }
    cam_v = {"count": 6, "accuracy": 0.5, "detected": 1.0, "side": 0.5, "distance": 1.0,
             "focal_scale": 0.61}  # fmt: skip
    card["accuracy_val"] = {  # the page shows blur 0 by source; the card holds every level
        f"real-s1-b{b}": {"split": "val", "count": 6, "accuracy": 0.5, "by_source": {
            "cam-v": {**cam_v, "accuracy": 0.5 if b == 0 else 0.25}}}
        for b in (0, 3)
    }  # fmt: skip
    (models / "tiny.json").write_text(json.dumps(card))
    page = write_catalog(models).read_text()
    assert "Real val sources (the model was selected on them), `real-s1-b0`:" in page
    assert "| `cam-v` | 6 | 50.0 % | 100.0 % | 100.0 % | 50.0 % | 0.61 |" in page
    assert "`real-s1-b3`" not in page and "| `cam-v` | 6 | 25.0 %" not in page
    assert "| `tiny` |  | spec | 80x60 |" in page and "| 25.0 % |" in page
    assert "| test |  | no model of this object is marked pick | `tiny` |" in page
    assert "| `cam-a` | 6 | 33.3 % | 100.0 % | 66.7 % | 50.0 % | 1.73 |" in page
    assert "| `negatives` | 4 | 0.0 % | - | - | - | - |" in page
    assert "how it was made" in page and "planar-pose catalog" in page
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no model card"):
        write_catalog(empty)


def test_a_card_gets_its_recipe_rebuild_commands_and_role_in_both_copies(tmp_path):
    """`planar-pose card`: the .json and the graph's copy rewritten alike, the graph kept;
    the recipe recorded relative to the repository; the catalog's pick table says it."""
    from typer.testing import CliRunner

    from train.cli import app
    from train.network.catalog import write_catalog

    ckpt, _ = _checkpoint(tmp_path, (80, 60))
    models = tmp_path / "models"
    path, card = export(ckpt, "tiny", models)
    graph = onnx.load(str(path)).graph
    recipe = REPO_ROOT / "recipes" / "chessboard-spec-80x60.toml"
    args = ["card", str(path), "--recipe", str(recipe), "--rebuild", "step one"]
    args += ["--rebuild", "step two", "--role", "pick", "--use", "for the test object"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    new = json.loads((models / "tiny.json").read_text())
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(meta["model_card"]) == new and onnx.load(str(path)).graph == graph
    assert new["training"]["recipe"] == "recipes/chessboard-spec-80x60.toml"
    assert new["training"]["rebuild"] == ["step one", "step two"]
    assert (new["role"], new["use"]) == ("pick", "for the test object")
    assert new["accuracy"] == card["accuracy"] and new["architecture"].startswith("spec: ")
    assert "| test | `tiny` | for the test object |  |" in write_catalog(models).read_text()
    result = CliRunner().invoke(app, ["card", str(path), "--role", "best"])
    assert result.exit_code == 1 and "role must be one of pick, ablation" in result.output
    result = CliRunner().invoke(app, ["card", str(path), "--recipe", str(tmp_path / "no.toml")])
    assert result.exit_code == 1 and "recipe not found" in result.output


def test_a_regraphed_graph_takes_the_focal_prior_its_profile_states_now():
    """A prior chosen after training (the ChArUco profile's 0.53 x) reaches a regraphed
    model's graph and card; a profile that cannot be loaded keeps the card's own."""
    from service.core.profile import load_profile
    from train.network.export import _camera_card, with_current_prior
    from train.network.model import build_network

    stated = load_profile("charuco").focal_prior
    assert stated != 0.8
    entry = load_profile("charuco").manifest_entry() | {"focal_prior": 0.8}  # as trained
    profile = with_current_prior(entry)
    assert profile == entry | {"focal_prior": stated}
    assert _camera_card(profile)["focal_prior_x_spec"] == stated
    from service.core.geometry import intrinsics

    net = build_network("corners", (160, 120), profile=profile)
    spec_fx = float(intrinsics((160, 120))[0, 0])
    assert float(net.focal) == pytest.approx(stated * spec_fx)  # the graph's prior camera
    unknown = {"name": "no-such-object", "focal_prior": 0.8}
    assert with_current_prior(unknown) == unknown and with_current_prior({}) == {}


def test_a_corner_graph_is_regraphed_with_the_zoom_inputs(tmp_path):
    """`export --regraph`: a shipped corner graph of an older form (no `view`, no `pattern`)
    comes back from its own weights with both, answering as before with the default view."""
    from typer.testing import CliRunner

    from train.cli import app
    from train.network import corners as corner_net
    from train.network.export import recard
    from train.network.onnx_weights import corner_net_from_onnx
    from train.real.realset import build_real_dataset

    old = REPO_ROOT / "tests" / "fixtures" / "corners-3.4.0-no-offsets.onnx"
    real = tmp_path / "real-s2-b0"
    build_real_dataset(REAL, real, size=2, blur=0, profile="chessboard", seed=0)
    path, card = recard(old, "re", tmp_path, [real], split="all", version="9.9.9")
    before = json.loads(old.with_suffix(".json").read_text())
    assert card["version"] == "9.9.9" and card["regraphed_from"] == before["version"]
    rebuild = card["training"].pop("rebuild")  # the regraph is its last step
    assert rebuild[:-1] == before["training"].get("rebuild", [])
    assert rebuild[-1].startswith(f"planar-pose export {old.relative_to(REPO_ROOT)} --name re")
    assert "--regraph --version 9.9.9 --eval" in rebuild[-1]
    assert card["training"] == {k: v for k, v in before["training"].items() if k != "rebuild"}
    assert "view" in card["input_format"]
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    outputs = ["probabilities", "corners", "pattern", "undistorted"]
    assert [o.name for o in session.get_outputs()] == outputs
    assert [i.name for i in session.get_overridable_initializers()] == [
        "pixel_aspect",
        "view",
        "focal",
    ]
    assert card["camera_model"]["focal_prior_x_spec"] == corner_net.FOCAL_PRIOR
    assert card["camera_model"]["focal_prior_barrel_limit"] == corner_net.BARREL_LIMIT
    photos = sorted(REAL.glob("*.jpg"))[:4]
    x = np.stack([to_network_input(read_rgb(p), (160, 120)) for p in photos])
    # the weights answer as the network read back from the old graph does with this version's
    # geometry (the lens fit of the corners, the camera model): the same corners and
    # probabilities
    net, _ = corner_net_from_onnx(old)
    with torch.no_grad():
        want_corners = net.eval().corners(torch.from_numpy(x)).numpy()
        want = net.logits(torch.from_numpy(x)).exp().numpy()
    assert np.abs(session.run(["corners"], {"image": x})[0] - want_corners).max() < 5e-3
    assert np.abs(session.run(["probabilities"], {"image": x})[0] - want).max() < 1e-3
    runner = CliRunner()
    args = ["export", "--name", "x", "--out-dir", str(tmp_path / "cli"), "--regraph"]
    result = runner.invoke(app, [*args, str(tmp_path / "best.pt"), "--eval", str(real)])
    assert result.exit_code == 2 and "--regraph takes a corner .onnx model" in result.output
    spec = REPO_ROOT / "models" / "chessboard-spec-160x120.onnx"
    result = runner.invoke(app, [*args, str(spec), "--eval", str(real)])
    assert result.exit_code == 1 and "not a planar-pose corner network" in result.output
    result = runner.invoke(app, [*args, str(old), "--eval-val", str(tmp_path / "none")])
    assert result.exit_code == 1 and "not a data set (no labels.csv)" in result.output
