"""The SDK's stream (sync and async) and the `planar-pose-client watch` command against a live
server: answers in order as /v1/predict gives them, bad frames, refusals, a server that is
down, and the video written with --out read back."""

from __future__ import annotations

import asyncio
import json
import socket
import subprocess
import sys
from collections.abc import AsyncIterator
from pathlib import Path

import numpy as np
import pytest
from live_support import API_KEY, PHOTO, Server, jpeg, predict_each, read_video
from planar_pose_client import AsyncPoseClient, AuthError, PoseClient, PoseConnectionError
from planar_pose_client.errors import InvalidRequestError
from planar_pose_client.stream import FrameError, StreamPrediction

CLIENT = [str(Path(sys.executable).with_name("planar-pose-client"))]


def test_sync_stream_answers_every_frame_in_order(
    server: Server, video: tuple[Path, list[int]]
) -> None:
    frames = [jpeg(f) for f in read_video(video[0])]
    expected = predict_each(server.url, frames, "sliding")
    with PoseClient(server.url) as client:
        answers = list(client.stream(frames, mode="sliding"))
    assert all(isinstance(a, StreamPrediction) for a in answers)
    assert [a.seq for a in answers] == list(range(len(frames)))
    assert [a.class_id for a in answers] == [e["class_id"] for e in expected]
    assert [a.box.model_dump() if a.box else None for a in answers] == [e["box"] for e in expected]


def test_sync_stream_takes_paths_arrays_and_reports_bad_frames(server: Server) -> None:
    rgb = np.ascontiguousarray(np.asarray(read_video_rgb(PHOTO)))
    with PoseClient(server.url) as client:
        answers = list(client.stream([PHOTO, b"garbage", rgb, PHOTO]))
    assert [a.ok for a in answers] == [True, False, True, True]
    bad = answers[1]
    assert isinstance(bad, FrameError) and bad.code == "undecodable_image" and bad.seq == 1
    first, last = answers[0], answers[3]
    assert isinstance(first, StreamPrediction) and isinstance(last, StreamPrediction)
    assert last.class_id == first.class_id  # tracked from the first one's corners


def read_video_rgb(path: Path) -> np.ndarray:
    import cv2

    return cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)


def test_unlimited_window_lets_the_service_drop_frames(server: Server) -> None:
    frames = [PHOTO.read_bytes()] * 300
    with PoseClient(server.url) as client:
        answers = list(client.stream(frames, mode="sliding", window=None))
    assert answers[-1].seq == 299
    assert len(answers) + sum(a.dropped for a in answers) == 300
    assert sum(a.dropped for a in answers) > 0


def test_breaking_out_of_the_stream_closes_it(server: Server) -> None:
    with PoseClient(server.url) as client:
        for answer in client.stream(iter(lambda: PHOTO.read_bytes(), None)):  # endless
            if answer.seq == 20:
                break
        assert client.ready()


def test_async_stream_with_an_async_frame_source(server: Server) -> None:
    photo = PHOTO.read_bytes()
    (expected,) = predict_each(server.url, [photo], "whole")

    async def frames() -> AsyncIterator[bytes]:
        for _ in range(30):
            yield photo
            await asyncio.sleep(0)

    async def run() -> list[StreamPrediction | FrameError]:
        async with AsyncPoseClient(server.url) as client:
            return [a async for a in client.stream(frames(), smooth=0.5)]

    answers = asyncio.run(run())
    assert [a.seq for a in answers] == list(range(30))
    assert all(isinstance(a, StreamPrediction) for a in answers)
    assert answers[-1].class_id == expected["class_id"]  # same frame: smoothing converges


def test_refusals_raise_the_matching_errors(server: Server, secured: Server) -> None:
    with PoseClient(secured.url, api_key="wrong") as client, pytest.raises(AuthError) as auth:
        list(client.stream([PHOTO]))
    assert auth.value.status == 401 and auth.value.code == "unauthorized"
    with PoseClient(secured.url, api_key=API_KEY) as client:
        assert [a.seq for a in client.stream([PHOTO])] == [0]
    with PoseClient(server.url) as client, pytest.raises(InvalidRequestError) as bad:
        list(client.stream([PHOTO], smooth=2.0))
    assert "smooth" in bad.value.message


def _dead_url() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"http://127.0.0.1:{sock.getsockname()[1]}"  # nobody listens once closed


def test_a_server_that_is_down_is_a_connection_error() -> None:
    with PoseClient(_dead_url(), timeout=5) as client, pytest.raises(PoseConnectionError) as e:
        list(client.stream([PHOTO]))
    assert "cannot open the stream" in str(e.value)


def _watch(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CLIENT, "watch", *args], capture_output=True, text=True, timeout=120, check=False
    )


def test_watch_prints_a_line_per_frame_and_writes_the_drawn_video(
    server: Server, video: tuple[Path, list[int]], tmp_path: Path
) -> None:
    out = tmp_path / "drawn.mp4"
    done = _watch(str(video[0]), "--mode", "sliding", "--out", str(out), "--url", server.url)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    frames = read_video(video[0])
    expected = predict_each(server.url, [jpeg(f) for f in frames], "sliding")
    assert len(lines) == len(frames) + 1
    for line, want in zip(lines, expected, strict=False):
        assert want["region"]["label"] in line and " fps" in line
    assert lines[-1].startswith(f"{len(frames)} frame(s) answered, 0 dropped, 0 refused")
    drawn = read_video(out)
    assert len(drawn) == len(frames) and drawn[0].shape == frames[0].shape
    # the label banner is drawn in the top-left corner: black background, white text
    assert drawn[0][:30, :200].mean() < frames[0][:30, :200].mean()


def test_watch_json_lines_and_max_frames(server: Server, video: tuple[Path, list[int]]) -> None:
    done = _watch(str(video[0]), "--max-frames", "5", "--json", "--url", server.url)
    assert done.returncode == 0, done.stderr
    answers = [json.loads(line) for line in done.stdout.splitlines()]
    assert [a["seq"] for a in answers] == list(range(5))
    assert all(len(a["probabilities"]) == 9 for a in answers)
    assert done.stderr.startswith("5 frame(s) answered")  # the summary leaves stdout to JSON


def test_watch_errors_have_their_exit_codes(server: Server, tmp_path: Path) -> None:
    missing = _watch(str(tmp_path / "nope.mp4"), "--url", server.url)
    assert missing.returncode == 5 and "no such video file" in missing.stderr
    not_video = tmp_path / "text.mp4"
    not_video.write_text("hello")
    unreadable = _watch(str(not_video), "--url", server.url)
    assert unreadable.returncode == 5 and "not a video OpenCV can read" in unreadable.stderr
    camera = _watch("57", "--url", server.url)
    assert camera.returncode == 5 and "camera 57 does not open" in camera.stderr
    video = tmp_path / "one.mp4"
    import cv2

    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 5, (640, 480))
    writer.write(cv2.imread(str(PHOTO)))
    writer.release()
    down = _watch(str(video), "--url", _dead_url(), "--timeout", "5")
    assert down.returncode == 3 and "cannot open the stream" in down.stderr
    for result in (missing, unreadable, camera, down):
        assert "Traceback" not in result.stderr
