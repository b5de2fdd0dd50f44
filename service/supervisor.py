"""The supervisor of `planar-pose-serve --workers N`: uvicorn's, passing SIGTERM on at once
and letting go of the listening socket."""

from __future__ import annotations

import logging
import signal
from socket import socket
from types import FrameType

from uvicorn.config import Config
from uvicorn.supervisors import Multiprocess

log = logging.getLogger("uvicorn.error")


class Supervisor(Multiprocess):
    """uvicorn's supervisor of worker processes, with two changes for a clean shutdown:

    * SIGTERM stops its loop at once (uvicorn's looks at its signals every 0.5 s), so the
      workers start draining (service/api/drain.py) and /readyz answers 503 right away;
    * it closes its copy of the listening socket when it stops the workers: once they have
      drained and closed theirs, a new connection is refused instead of waiting in the
      backlog of a socket no process accepts from, to be reset when this one exits.
    """

    def __init__(self, config: Config, sockets: list[socket]) -> None:
        super().__init__(config, sockets)
        signal.signal(signal.SIGTERM, self._on_sigterm)

    def _on_sigterm(self, signum: int, frame: FrameType | None) -> None:
        self.should_exit.set()  # wakes the loop's wait: the workers are stopped next

    def terminate_all(self) -> None:
        """Close the listening socket here, then SIGTERM every worker."""
        log.info("Stopping the worker processes")
        for sock in self.sockets:
            sock.close()
        super().terminate_all()
