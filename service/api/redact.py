"""No secrets in the logs: the values of query-string parameters that carry credentials
(`?api_key=`, which the stream takes from browsers, `token`, `key`, ...) are replaced by `***`
in every line uvicorn logs (its access log, and the WebSocket lines it writes to its error
log) and in the service's own.

A `logging.Filter` on those loggers rewrites each record's message and arguments; a parameter
name is matched after percent-decoding (`api%5Fkey` is `api_key` to the app too).
"""

from __future__ import annotations

import logging
import re
from urllib.parse import unquote_plus

#: Query parameters whose values are credentials (compared lower-case, `-` read as `_`).
SECRET_PARAMETERS = frozenset(
    {
        "api_key",
        "apikey",
        "key",
        "x_api_key",
        "token",
        "access_token",
        "id_token",
        "refresh_token",
        "auth",
        "authorization",
        "password",
        "passwd",
        "secret",
        "client_secret",
        "signature",
        "sig",
    }
)
#: The loggers whose lines carry URLs: uvicorn's access log, its error log (WebSocket lines),
#: the service's own.
LOGGERS = ("uvicorn.access", "uvicorn.error", "uvicorn.error.pose")
MASK = "***"

_PARAMETER = re.compile(r"(?P<lead>[?&;])(?P<name>[^=&;?\s\"']+)=(?P<value>[^&;\s\"']*)")


def _is_secret(name: str) -> bool:
    return unquote_plus(name).strip().lower().replace("-", "_") in SECRET_PARAMETERS


def redact(text: str) -> str:
    """`text` with the value of every secret query parameter in it replaced by `***`."""
    if "=" not in text:
        return text

    def mask(match: re.Match[str]) -> str:
        if not _is_secret(match["name"]) or not match["value"]:
            return match[0]
        return f"{match['lead']}{match['name']}={MASK}"

    return _PARAMETER.sub(mask, text)


class RedactSecrets(logging.Filter):
    """Rewrites a record's message and string arguments with `redact` (never drops one)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.msg, str):
            record.msg = redact(record.msg)
        if isinstance(record.args, tuple):
            record.args = tuple(redact(a) if isinstance(a, str) else a for a in record.args)
        elif isinstance(record.args, dict):
            record.args = {
                k: redact(v) if isinstance(v, str) else v for k, v in record.args.items()
            }
        return True


def install() -> None:
    """Put the filter on `LOGGERS` (once per process; uvicorn's logging configuration keeps
    the filters of a logger)."""
    for name in LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(f, RedactSecrets) for f in logger.filters):
            logger.addFilter(RedactSecrets())
