"""The supervisor of `planar-pose-serve --workers N`: uvicorn's, letting go of the socket."""

from __future__ import annotations

from uvicorn.supervisors import Multiprocess


class Supervisor(Multiprocess):
    """uvicorn's supervisor of worker processes, which also lets go of its copy of the
    listening socket when it stops them: once the workers have drained (service/drain.py)
    and closed theirs, a new connection is refused instead of waiting in the backlog of a
    socket no process accepts from, to be reset when this one exits."""

    def terminate_all(self) -> None:
        """Close the listening socket here, then SIGTERM every worker."""
        for sock in self.sockets:
            sock.close()
        super().terminate_all()
