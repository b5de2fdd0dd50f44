"""Shutting down without a failed request: the drain after SIGTERM (`POSE_DRAIN_S`).

A load balancer (a Kubernetes Service, an ingress) keeps sending a terminating server new
requests for a few seconds, until it has seen the endpoint go. So on SIGTERM a worker first
*drains*: `/readyz` and `/v2/health/ready` answer 503 at once, every answer carries
`Connection: close` (a client's keep-alive connection moves on), and requests keep being
accepted and answered for `POSE_DRAIN_S` seconds. Then uvicorn's own shutdown runs: the
listener closes (new connections are refused, not reset), the requests in flight finish
(within `POSE_GRACEFUL_TIMEOUT_S`), the process exits.

The drain holds back uvicorn's SIGTERM handler (installed before the app starts) by wrapping
it; with worker processes the supervisor passes SIGTERM to every worker, and each drains.
SIGINT (Ctrl+C) still stops at once.
"""

from __future__ import annotations

import asyncio
import logging
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

log = logging.getLogger("uvicorn.error.pose")


class Drain:
    """Whether this process drains, and since when; shared by the routes and middleware."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.started: float | None = None  # loop time the drain began

    @property
    def active(self) -> bool:
        return self.started is not None

    def begin(self, loop: asyncio.AbstractEventLoop) -> None:
        self.started = loop.time()

    def problem(self) -> str | None:
        """Why /readyz answers 503 while draining, None otherwise."""
        if self.started is None:
            return None
        return f"shutting down (SIGTERM): answering requests for {self.seconds:g} s, then exiting"


def hold_back_sigterm(drain: Drain, loop: asyncio.AbstractEventLoop) -> bool:
    """Wrap the SIGTERM handler (uvicorn's) so that it runs `drain.seconds` after the signal,
    the drain beginning at once. Only in the main thread, with a Python handler installed and
    a drain time above 0; returns whether it did."""
    if drain.seconds <= 0 or threading.current_thread() is not threading.main_thread():
        return False
    previous = signal.getsignal(signal.SIGTERM)
    if not callable(previous):
        return False
    stop: Callable[[int, FrameType | None], Any] = previous

    def on_sigterm(signum: int, frame: FrameType | None) -> None:
        if drain.active:
            return  # one drain; SIGINT stops at once
        drain.begin(loop)
        log.info("SIGTERM: draining for %g s (/readyz 503), then shutting down", drain.seconds)
        loop.call_soon_threadsafe(loop.call_later, drain.seconds, stop, signum, None)

    signal.signal(signal.SIGTERM, on_sigterm)
    return True


class DrainMiddleware:
    """While draining, every HTTP answer carries `Connection: close`."""

    def __init__(self, app: ASGIApp, drain: Drain) -> None:
        self.app, self.drain = app, drain

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or not self.drain.active:
            await self.app(scope, receive, send)
            return

        async def closing(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = [(k, v) for k, v in message.get("headers", []) if k != b"connection"]
                message = {**message, "headers": [*headers, (b"connection", b"close")]}
            await send(message)

        await self.app(scope, receive, closing)
