"""What the worker processes of one `planar-pose-serve --workers N` share, through files in
its runtime folder: which workers have their models (readiness) and a reload generation
counter (a reload asked of one worker is done by all)."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path


def alive(pid: int) -> bool:
    """Whether process `pid` runs (it may belong to another user)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class WorkerRuntime:
    """This worker's view of the runtime folder `root` shared with `expected - 1` others."""

    def __init__(self, root: Path, expected: int) -> None:
        self.root, self.expected = root, expected
        self.ready_dir = root / "ready"
        self.ready_dir.mkdir(parents=True, exist_ok=True)
        self.generation_file = root / "generation"
        self.seen = self.generation()

    def mark_ready(self) -> None:
        (self.ready_dir / str(os.getpid())).touch()

    def unmark(self) -> None:
        (self.ready_dir / str(os.getpid())).unlink(missing_ok=True)

    def ready_count(self) -> int:
        """Live workers that have loaded their models."""
        pids = [int(p.name) for p in self.ready_dir.iterdir() if p.name.isdigit()]
        return sum(alive(pid) for pid in pids)

    def generation(self) -> int:
        try:
            return int(self.generation_file.read_text() or 0)
        except (FileNotFoundError, ValueError):
            return 0

    def bump(self) -> int:
        """Count one reload (under a file lock); this worker has already done it."""
        with (self.root / "generation.lock").open("w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            value = self.generation() + 1
            tmp = self.root / f"generation.{os.getpid()}"
            tmp.write_text(str(value))
            tmp.replace(self.generation_file)
        self.seen = value
        return value

    def reload_asked(self) -> bool:
        """True once per reload asked of another worker since this one last looked."""
        value = self.generation()
        if value == self.seen:
            return False
        self.seen = value
        return True
