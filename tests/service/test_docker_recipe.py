"""The Dockerfile, replayed outside Docker (no engine here): the build stage's `pip install .`
into a fresh venv (torch must NOT be importable there), then the runtime stage's ENV, WORKDIR,
CMD and HEALTHCHECK, all read from the Dockerfile, against a real photo.

Container paths (/opt/venv, /app, /src) are mapped into a temporary folder; the port is a free
one; pip runs without --no-cache-dir so its local cache can be reused between runs.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest
from server_process import free_port, live_server
from service_support import PHOTO, ROOT, check_answer

from service.core.paths import DEFAULT_MODEL_NAME

DOCKERFILE = ROOT / "Dockerfile"


def instructions(text: str) -> tuple[dict[str, str], list[list[tuple[str, str]]]]:
    """Dockerfile -> (ARGs before the first FROM with their defaults, stages), each stage a
    list of (INSTRUCTION, arguments); continuations joined, ${ARG} in FROM substituted."""
    joined = re.sub(r"\\\n\s*", " ", text)
    args: dict[str, str] = {}
    stages: list[list[tuple[str, str]]] = []
    for line in joined.splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        word, _, rest = line.partition(" ")
        word, rest = word.upper(), rest.strip()
        if word == "ARG" and not stages:
            name, _, default = rest.partition("=")
            args[name] = default
            continue
        if word == "FROM":
            stages.append([])
            rest = re.sub(r"\$\{(\w+)\}", lambda m: args[m.group(1)], rest)
        stages[-1].append((word, rest))
    return args, stages


def args_of(stage: list[tuple[str, str]], word: str) -> list[str]:
    return [args for w, args in stage if w == word]


BUILD_ARGS, STAGES = instructions(DOCKERFILE.read_text())
BUILD, RUNTIME = STAGES


def exec_form(args: str) -> list[str]:
    value = json.loads(args)
    assert isinstance(value, list), f"use the exec (JSON) form: {args}"
    return value


def test_recipe_shape() -> None:
    assert len(STAGES) == 2
    assert re.fullmatch(r"python:3\.1\d+-slim", BUILD_ARGS["BASE_IMAGE"])
    for stage in STAGES:
        assert args_of(stage, "FROM")[0].startswith(BUILD_ARGS["BASE_IMAGE"] + " AS ")
    assert args_of(RUNTIME, "EXPOSE") == ["8000"]
    user = args_of(RUNTIME, "USER")[-1]
    assert user not in ("root", "0")
    runtime_runs = " ".join(args_of(RUNTIME, "RUN"))
    assert not re.search(r"pip|apt|gcc|torch", runtime_runs), runtime_runs
    assert not any("torch" in args for stage in STAGES for _, args in stage)
    healthcheck = args_of(RUNTIME, "HEALTHCHECK")[0]
    assert "/healthz" in healthcheck and "curl" not in healthcheck
    assert exec_form(args_of(RUNTIME, "CMD")[0])[0] == "planar-pose-serve"
    copied = " ".join(args_of(BUILD, "COPY") + args_of(RUNTIME, "COPY"))
    assert "train" not in copied, copied  # no training code or data in the image


def mapper(tmp: Path) -> Callable[[str], str]:
    """Container path -> path under `tmp`, applied inside any string."""
    roots = ("/opt/venv", "/app", "/src")

    def to_tmp(text: str) -> str:
        for root in roots:
            text = re.sub(rf"(?<![\w/]){re.escape(root)}(?=/|\b|$)", str(tmp) + root, text)
        return text

    return to_tmp


def copy_into(
    stage: list[tuple[str, str]], tmp: Path, to_tmp: Callable[[str], str], workdir: str
) -> None:
    """Replay the stage's COPY lines from the repo (build context) into the mapped paths."""
    for args in args_of(stage, "COPY"):
        if args.startswith("--from="):
            continue  # the build stage's venv is already at its mapped path
        *sources, dest = shlex.split(args)
        target = Path(to_tmp(dest if dest.startswith("/") else f"{workdir}/{dest}"))
        expanded = [p for source in sources for p in sorted(ROOT.glob(source))]
        assert expanded, f"COPY {args}: nothing matches in the build context"
        for src in expanded:
            if src.is_dir():  # .dockerignore drops caches and the real photos
                ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "real")
                shutil.copytree(src, target, ignore=ignore, dirs_exist_ok=True)
            else:
                out = target / src.name if dest.endswith("/") or len(expanded) > 1 else target
                out.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(src, out)


@pytest.mark.slow
@pytest.mark.timeout(1200)  # a fresh venv's pip install, minutes on a loaded machine
def test_image_install_and_command_outside_docker(tmp_path: Path) -> None:
    to_tmp = mapper(tmp_path)
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("POSE_", "VIRTUAL_ENV"))}
    clean["PATH"] = os.pathsep.join(
        p for p in clean["PATH"].split(os.pathsep) if not p.startswith(str(ROOT / ".venv"))
    )
    python_dir = str(Path(sys.base_prefix) / "bin")  # "python" of the base image
    build_env = {**clean, "PATH": python_dir + os.pathsep + clean["PATH"]}

    # build stage: COPY, then RUN in WORKDIR
    workdir = args_of(BUILD, "WORKDIR")[-1]
    copy_into(BUILD, tmp_path, to_tmp, workdir)
    for run in args_of(BUILD, "RUN"):
        command = to_tmp(run).replace("--no-cache-dir", "")
        done = subprocess.run(
            ["bash", "-c", command],
            cwd=to_tmp(workdir),
            env=build_env,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    # runtime stage: COPY, ENV, WORKDIR
    app_dir = args_of(RUNTIME, "WORKDIR")[-1]
    copy_into(RUNTIME, tmp_path, to_tmp, app_dir)
    env = dict(build_env)
    for args in args_of(RUNTIME, "ENV"):
        for pair in shlex.split(args):
            key, _, value = pair.partition("=")
            env[key] = to_tmp(value).replace("$PATH", env["PATH"])
    cwd = Path(to_tmp(app_dir))

    venv_python = Path(to_tmp("/opt/venv")) / "bin" / "python"
    no_torch = subprocess.run(
        [str(venv_python), "-c", "import torch"], env=env, cwd=cwd, capture_output=True, text=True
    )
    assert no_torch.returncode != 0 and "No module named 'torch'" in no_torch.stderr
    where = subprocess.run(
        [str(venv_python), "-c", "import service; print(service.__file__)"],
        env=env,
        cwd=cwd,
        capture_output=True,
        text=True,
        check=True,
    )
    assert where.stdout.startswith(to_tmp("/opt/venv")), where.stdout  # installed, not the repo

    # CMD and HEALTHCHECK, with a free port instead of 8000
    port = free_port()
    cmd = exec_form(args_of(RUNTIME, "CMD")[0])
    cmd[cmd.index("--port") + 1] = "{port}"
    executable = shutil.which(cmd[0], path=env["PATH"])
    assert executable and executable.startswith(to_tmp("/opt/venv"))
    with live_server([executable, *cmd[1:]], tmp_path / "serve.log", env, cwd=cwd) as (base, _):
        port = int(base.rsplit(":", 1)[1])
        health = exec_form(args_of(RUNTIME, "HEALTHCHECK")[0].split("CMD", 1)[1].strip())
        health = [part.replace(":8000", f":{port}") for part in health]
        health[0] = shutil.which(health[0], path=env["PATH"]) or health[0]
        assert subprocess.run(health, env=env, cwd=cwd, timeout=30).returncode == 0
        r = httpx.post(
            base + "/v1/predict?mode=sliding",
            content=PHOTO,
            headers={"content-type": "image/jpeg"},
            timeout=60,
        )
        assert r.status_code == 200, r.text
        check_answer(r.json(), "sliding", [(640, 480)])
        assert httpx.get(base + "/v1/model").json()["name"] == DEFAULT_MODEL_NAME
    no_train = subprocess.run(
        [str(venv_python), "-c", "import train"], env=env, cwd=cwd, capture_output=True, text=True
    )
    assert no_train.returncode != 0 and "No module named 'train'" in no_train.stderr


@pytest.mark.parametrize("line", ["pyproject.toml", "README.md", "service/", "models/*.onnx"])
def test_dockerignore_keeps_what_the_build_copies(line: str) -> None:
    assert f"!{line}" in (ROOT / ".dockerignore").read_text().splitlines()


def test_dockerignore_keeps_training_code_out() -> None:
    lines = (ROOT / ".dockerignore").read_text().splitlines()
    assert "**" in lines  # everything is excluded unless listed
    assert not any(line.startswith("!train") for line in lines)
