"""A scripted stdlib HTTP server in a thread, to watch what the client does (retries, headers)
without the real service: it answers each request with the next (status, JSON body) of its
script and records every request it got."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any


@dataclass
class Script:
    """Answers in order, the last one repeating: (status, JSON-able body, or str sent as
    text/html). `requests` gets (method, path, headers)."""

    answers: list[tuple[int, Any]]
    requests: list[tuple[str, str, dict[str, str]]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def next_answer(self, method: str, path: str, headers: dict[str, str]) -> tuple[int, Any]:
        with self.lock:
            self.requests.append((method, path, headers))
            return self.answers[min(len(self.requests), len(self.answers)) - 1]


def prediction_body(filenames: list[str]) -> dict[str, Any]:
    """A valid POST /v1/predict answer for `filenames`, all of class 6 (far, x-, y+)."""
    probabilities = [0.02] * 9
    probabilities[6] = 0.84
    result = {
        "class_id": 6,
        "region": {"present": True, "depth": "far", "x": "-", "y": "+", "label": "far, x-, y+"},
        "probabilities": probabilities,
        "confidence": 0.84,
        "box": None,
        "elapsed_ms": 1.5,
    }
    return {
        "model": "fake",
        "mode": "whole",
        "results": [{"filename": name, **result} for name in filenames],
    }


def error_body(code: str, message: str) -> dict[str, Any]:
    return {"error": {"code": code, "message": message}}


@contextmanager
def serve(script: Script) -> Iterator[str]:
    """Run the scripted server on 127.0.0.1 with a free port; yields its base URL."""

    class Handler(BaseHTTPRequestHandler):
        def _answer(self) -> None:
            length = int(self.headers.get("Content-Length") or 0)
            self.rfile.read(length)
            status, body = script.next_answer(self.command, self.path, dict(self.headers))
            is_text = isinstance(body, str)  # e.g. a proxy's HTML error page
            data = body.encode() if is_text else json.dumps(body).encode()
            self.send_response(status)
            self.send_header("Content-Type", "text/html" if is_text else "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        do_GET = do_POST = _answer

        def log_message(self, format: str, *args: Any) -> None:  # keep the test output clean
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
