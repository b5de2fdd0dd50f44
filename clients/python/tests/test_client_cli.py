"""The `planar-pose-client` command against the real service: table and JSON output, the model
card, and one-line errors with their exit codes."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from live_service import API_KEY, DEFAULT_NAME, MAX_IMAGES, OTHER_MODEL, REAL
from planar_pose_client import PoseClient
from planar_pose_client.cli import ExitCode, app
from typer.testing import CliRunner

runner = CliRunner()


def invoke(*args: str, env: dict[str, str] | None = None):
    return runner.invoke(app, list(args), env=env)


def assert_one_line_error(result, code: ExitCode, text: str) -> None:
    assert result.exit_code == code, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and text in lines[0], result.stderr
    assert "Traceback" not in result.output


def test_predict_prints_a_table(service_url, photos):
    result = invoke("predict", *map(str, photos), "--url", service_url)
    assert result.exit_code == 0, result.output
    with PoseClient(service_url) as client:
        expected = client.predict_many(photos)
    for p in expected:
        assert p.filename in result.stdout and p.label in result.stdout
        assert f"{p.confidence:.3f}" in result.stdout
    assert "3 image(s), mode whole" in result.stdout
    known = invoke("predict", str(photos[0]), "--fx", "1600", "--url", service_url)
    assert known.exit_code == 0 and "1600" in known.stdout and "(query)" in known.stdout


def test_predict_sends_batches_within_the_service_limit(service_url):
    many = sorted(REAL.glob("*.jpg"))[: MAX_IMAGES * 2 + 1]
    result = invoke(
        "predict", *map(str, many), "--batch", str(MAX_IMAGES), "--json", "--url", service_url
    )
    assert result.exit_code == 0, result.output
    assert [a["filename"] for a in json.loads(result.stdout)] == [p.name for p in many]
    too_big = invoke("predict", *map(str, many), "--batch", "100", "--url", service_url)
    assert_one_line_error(too_big, ExitCode.BAD_INPUT, "HTTP 413 too_many_images")


def test_predict_json_matches_the_sdk(service_url, photos):
    result = invoke("predict", str(photos[0]), str(photos[1]), "--json", "--url", service_url)
    assert result.exit_code == 0, result.output
    answer = json.loads(result.stdout)
    with PoseClient(service_url) as client:
        expected = client.predict_many(photos[:2])
    assert [a["filename"] for a in answer] == [photos[0].name, photos[1].name]
    assert [a["class_id"] for a in answer] == [p.class_id for p in expected]
    assert answer[0]["region"]["label"] == expected[0].label


def test_predict_sliding_shows_boxes(service_url, photos):
    result = invoke("predict", str(photos[0]), "--mode", "sliding", "--json", "--url", service_url)
    assert result.exit_code == 0, result.output
    (answer,) = json.loads(result.stdout)
    assert answer["class_id"] == 0 or set(answer["box"]) == {"x", "y", "w", "h"}


def test_info_summarises_the_card(service_url):
    with PoseClient(service_url) as client:
        card = client.model_info()
    table = invoke("info", "--url", service_url)
    assert table.exit_code == 0, table.output
    assert card.name in table.stdout and card.version in table.stdout
    assert f"{card.input[0]}x{card.input[1]}" in table.stdout
    raw = invoke("info", "--json", "--url", service_url)
    assert json.loads(raw.stdout)["name"] == card.name


def test_status(service_url):
    result = invoke("status", "--url", service_url)
    assert result.exit_code == 0 and "alive, ready" in result.stdout


def test_not_ready(unready_url, photos):
    status = invoke("status", "--url", unready_url)
    assert status.exit_code == ExitCode.UNREACHABLE and "alive, not ready" in status.stdout
    result = invoke("predict", str(photos[0]), "--url", unready_url, "--retries", "0")
    assert_one_line_error(result, ExitCode.UNREACHABLE, "HTTP 503 not_ready")


def test_api_key_from_option_or_environment(secured_url, photos):
    assert_one_line_error(
        invoke("predict", str(photos[0]), "--url", secured_url),
        ExitCode.AUTH,
        "HTTP 401",
    )
    assert_one_line_error(
        invoke("info", "--url", secured_url, "--api-key", "wrong"), ExitCode.AUTH, "HTTP 401"
    )
    by_option = invoke("predict", str(photos[0]), "--url", secured_url, "--api-key", API_KEY)
    assert by_option.exit_code == 0, by_option.output
    by_env = invoke(
        "predict", str(photos[0]), "--url", secured_url, env={"PLANAR_POSE_API_KEY": API_KEY}
    )
    assert by_env.exit_code == 0 and photos[0].name in by_env.stdout


def test_bad_image_and_missing_file(service_url, tmp_path: Path):
    garbage = tmp_path / "garbage.jpg"
    garbage.write_bytes(b"definitely not a JPEG")
    assert_one_line_error(
        invoke("predict", str(garbage), "--url", service_url), ExitCode.BAD_INPUT, "HTTP 400"
    )
    # Checked before anything is sent: the good photo first does not get a result printed.
    missing = invoke("predict", str(REAL / "left01.jpg"), str(tmp_path / "nope.jpg"))
    assert_one_line_error(missing, ExitCode.BAD_INPUT, "no such image file")
    assert missing.stdout == ""
    assert_one_line_error(
        invoke("predict", str(tmp_path), "--url", service_url),
        ExitCode.BAD_INPUT,
        "is a directory",
    )


def test_unreachable_server(photos):
    # Port 9 (discard) has no listener on the test machine.
    result = invoke("predict", str(photos[0]), "--url", "http://127.0.0.1:9", "--retries", "1")
    assert_one_line_error(result, ExitCode.UNREACHABLE, "cannot reach http://127.0.0.1:9")
    assert "(2 attempts)" in result.stderr
    status = invoke("status", "--url", "http://127.0.0.1:9")
    assert status.exit_code == ExitCode.UNREACHABLE and "not answering" in status.stdout


@pytest.mark.parametrize("url", ["localhost:8000", "http://"])
def test_bad_url(url, photos):
    result = invoke("info", "--url", url)
    assert_one_line_error(result, ExitCode.BAD_INPUT, "base_url must look like")


def test_installed_script_exits_cleanly(photos, tmp_path):
    script = Path(sys.executable).with_name("planar-pose-client")
    done = subprocess.run(
        [str(script), "predict", str(tmp_path / "missing.png"), "--url", "http://127.0.0.1:9"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == ExitCode.BAD_INPUT
    assert done.stderr.strip() == f"error: no such image file: {tmp_path / 'missing.png'}"


def test_models_command_and_the_model_option(folder_url, photos):
    listing = invoke("models", "--url", folder_url)
    assert listing.exit_code == 0, listing.output
    assert DEFAULT_NAME in listing.stdout and OTHER_MODEL in listing.stdout
    assert "training" in listing.stdout and "trained" in listing.stdout  # how each knows it
    assert re.search(r"\d+\.\d %", listing.stdout)  # what its card measured
    as_json = json.loads(invoke("models", "--json", "--url", folder_url).stdout)
    assert as_json["default"] == DEFAULT_NAME
    large = OTHER_MODEL
    result = invoke("predict", str(photos[0]), "--model", large, "--json", "--url", folder_url)
    assert result.exit_code == 0, result.output
    with PoseClient(folder_url) as client:
        expected = client.predict(photos[0], model=large)
    assert json.loads(result.stdout)[0]["probabilities"] == expected.probabilities
    unknown = invoke("predict", str(photos[0]), "--model", "nope", "--url", folder_url)
    assert_one_line_error(unknown, ExitCode.UNKNOWN_MODEL, "HTTP 404 model_not_found")
