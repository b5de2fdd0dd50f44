"""Build the service image with podman (no Docker engine or registry needed) and measure it.

    .venv/bin/python deploy/build_image.py [--tag localhost/planar-pose:latest] [--write-docs]

Steps: a containers.conf for this kind of machine (runc, no default ulimits: root cannot raise
the sandbox's NOFILE hard limit), the base image (`localhost/python:3.11-slim`: a stand-in for
python:3.11-slim made by mmdebstrap from Debian's packages, unless it exists), then
`podman build --build-arg BASE_IMAGE=... --format docker` (docker format keeps HEALTHCHECK).
Prints the build time, the image size and the size of its venv as JSON; `--write-docs` puts
them into docs/service.md between the `container-measured` markers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import tempfile
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASE = "localhost/python:3.11-slim"
TAG = "localhost/planar-pose:latest"
CA_BUNDLE = Path("/etc/ssl/certs/ca-certificates.crt")
CONTAINERS_CONF = '[containers]\ndefault_ulimits = []\n\n[engine]\nruntime = "runc"\n'
DOCS = ROOT / "docs" / "service.md"
MARKERS = ("<!-- container-measured:start -->", "<!-- container-measured:end -->")


class BuildError(RuntimeError):
    """A step failed; the message says which and ends with its output."""


@dataclass(frozen=True)
class Measured:
    tag: str
    base: str
    build_s: float
    image_mb: float
    venv_mb: float
    base_built: bool


def missing_tools() -> list[str]:
    """Of podman, runc and mmdebstrap, the ones not installed."""
    return [t for t in ("podman", "runc", "mmdebstrap") if shutil.which(t) is None]


def podman_env() -> dict[str, str]:
    """The environment for podman: our containers.conf (leaves /etc/containers alone)."""
    conf = Path(tempfile.gettempdir()) / "planar-pose-containers.conf"
    conf.write_text(CONTAINERS_CONF)
    return {**os.environ, "CONTAINERS_CONF": str(conf)}


def podman(
    *args: str, timeout: float = 900, check: bool = True
) -> subprocess.CompletedProcess[str]:
    """Run `podman args...`; BuildError with its output when it fails and `check`."""
    done = subprocess.run(
        ["podman", *args], env=podman_env(), capture_output=True, text=True, timeout=timeout
    )
    if check and done.returncode != 0:
        output = (done.stdout + done.stderr)[-3000:]
        raise BuildError(f"podman {' '.join(args[:2])} failed ({done.returncode}):\n{output}")
    return done


def ensure_base(base: str = BASE) -> bool:
    """Make the stand-in base image unless `base` exists; True when it was made now."""
    if podman("image", "exists", base, check=False).returncode == 0:
        return False
    with tempfile.TemporaryDirectory() as tmp:
        tar = Path(tmp) / "base.tar"
        done = subprocess.run(
            [
                "mmdebstrap",
                "--quiet",
                "--variant=minbase",
                "--hook-dir=/usr/share/mmdebstrap/hooks/merged-usr",
                "--dpkgopt=path-exclude=/usr/share/man/*",
                "--dpkgopt=path-exclude=/usr/share/doc/*",
                "--dpkgopt=path-include=/usr/share/doc/*/copyright",
                "--include=python3,python3-venv,python-is-python3,ca-certificates,passwd",
                "--format=tar",
                "bookworm",
                str(tar),
            ],
            capture_output=True,
            text=True,
            timeout=900,
        )
        if done.returncode != 0:
            raise BuildError(f"mmdebstrap failed ({done.returncode}):\n{done.stderr[-3000:]}")
        podman(
            "import", "--change", "ENV LANG=C.UTF-8", "--change", 'CMD ["python3"]', str(tar), base
        )
    return True


def build(tag: str = TAG, base: str = BASE, no_cache: bool = False) -> Measured:
    """Build the Dockerfile at the repo root as `tag` on `base` (every layer anew with
    `no_cache`); measure it."""
    base_built = ensure_base(base)
    mounts = ["-v", f"{CA_BUNDLE}:{CA_BUNDLE}:ro"] if CA_BUNDLE.is_file() else []
    t0 = time.perf_counter()
    podman(
        "build", "--pull=never", "--format", "docker", "--build-arg", f"BASE_IMAGE={base}",
        *mounts, *(["--no-cache"] if no_cache else []), "-t", tag, str(ROOT),
    )  # fmt: skip
    build_s = time.perf_counter() - t0
    size = int(podman("image", "inspect", "--format", "{{.Size}}", tag).stdout.strip())
    du = podman("run", "--rm", "--entrypoint", "du", tag, "-sk", "/opt/venv").stdout
    venv_kb = int(du.split()[0])
    return Measured(
        tag, base, round(build_s, 1), round(size / 1e6, 1), round(venv_kb / 1e3, 1), base_built
    )


def write_docs(measured: Measured, cold: bool, docs: Path = DOCS) -> None:
    """Replace the text between the markers of `docs` with the measurement."""
    text = docs.read_text()
    start, end = (text.index(m) for m in MARKERS)
    version = podman("--version").stdout.split()[-1]
    machine = f"{platform.machine()}, {os.cpu_count()} CPUs, podman {version}"
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    cache = "no layer cache" if cold else "layer cache as found"
    body = (
        f"\n_Written by `deploy/build_image.py --write-docs` on {when} ({machine})._\n\n"
        f"| image | base | build time | image size | of it, the venv |\n|---|---|---|---|---|\n"
        f"| `{measured.tag}` | `{measured.base}` | {measured.build_s:.0f} s ({cache}) "
        f"| {measured.image_mb:.0f} MB | {measured.venv_mb:.0f} MB |\n"
    )
    docs.write_text(text[: start + len(MARKERS[0])] + body + text[end:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tag", default=TAG)
    parser.add_argument("--base", default=BASE, help="base image (made by mmdebstrap if absent)")
    parser.add_argument("--no-cache", action="store_true", help="rebuild every layer")
    parser.add_argument(
        "--write-docs", action="store_true", help=f"update {DOCS.relative_to(ROOT)}"
    )
    args = parser.parse_args()
    if missing := missing_tools():
        raise SystemExit(
            f"error: not installed: {', '.join(missing)} (apt-get install podman runc mmdebstrap)"
        )
    try:
        measured = build(args.tag, args.base, args.no_cache)
    except BuildError as exc:
        raise SystemExit(f"error: {exc}") from None
    print(json.dumps(asdict(measured)))
    if args.write_docs:
        write_docs(measured, cold=args.no_cache)


if __name__ == "__main__":
    main()
