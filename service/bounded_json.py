"""JSON from clients, parsed with a bounded nesting depth.

Python's `json.loads` recurses once per nested array or object, so a small body nested some
thousands deep raises `RecursionError` (and a service answers 500). Here the depth is found
first, without recursion: the brackets outside strings are counted over the bytes with numpy
(a quote is a string's edge unless an odd run of backslashes precedes it), and text deeper
than the limit is refused as a `ValueError` like any other malformed JSON.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

#: The deepest nesting accepted by default: the Open Inference Protocol's deepest document (a
#: [N, 3, H, W] tensor as nested lists inside inputs) is 7 deep.
MAX_DEPTH = 32

_QUOTE, _BACKSLASH = ord('"'), ord("\\")
_OPEN, _CLOSE = (ord("["), ord("{")), (ord("]"), ord("}"))
_MARKS = np.zeros(256, bool)  # the bytes the depth depends on
_MARKS[[_QUOTE, _BACKSLASH, *_OPEN, *_CLOSE]] = True


class JSONTooDeepError(ValueError):
    """The text nests arrays and objects deeper than allowed."""


def nesting_depth(text: bytes) -> int:
    """The deepest nesting of arrays and objects in JSON `text` (0 for a scalar), counting
    only brackets outside strings. Linear in the length, no recursion; the work past one
    look-up per byte is on the quotes, backslashes and brackets only."""
    at = np.flatnonzero(_MARKS[np.frombuffer(text, np.uint8)])
    if not len(at):
        return 0
    codes = np.frombuffer(text, np.uint8)[at]
    step = np.arange(len(at))
    backslash = codes == _BACKSLASH
    # a backslash right before this mark (at the byte before), and the run it ends
    after_backslash = np.zeros(len(at), bool)
    after_backslash[1:] = backslash[:-1] & (at[:-1] + 1 == at[1:])
    run_start = np.maximum.accumulate(np.where(backslash & ~after_backslash, step, -1))
    run_before = np.zeros(len(at), np.int64)
    run_before[1:] = np.where(after_backslash[1:], step[:-1] - run_start[:-1] + 1, 0)
    edge = (codes == _QUOTE) & (run_before % 2 == 0)
    inside = (np.cumsum(edge) % 2 == 1) | edge  # a string's marks and its quotes
    opens = np.isin(codes, _OPEN) & ~inside
    closes = np.isin(codes, _CLOSE) & ~inside
    depth = np.cumsum(opens.astype(np.int64) - closes)
    return int(depth.max(initial=0))


def loads(text: bytes | str, max_depth: int = MAX_DEPTH) -> Any:
    """`json.loads(text)` for text nested at most `max_depth` deep; JSONTooDeepError beyond,
    json.JSONDecodeError (a ValueError) for text that is not JSON, UnicodeDecodeError (also
    a ValueError) for bytes that are not UTF-8."""
    raw = text.encode() if isinstance(text, str) else bytes(text)
    # no deeper than its opening brackets: most documents are decided without the scan
    depth = raw.count(b"[") + raw.count(b"{")
    if depth > max_depth:
        depth = nesting_depth(raw)
    if depth > max_depth:
        raise JSONTooDeepError(f"JSON nested {depth} deep, more than {max_depth}")
    try:
        return json.loads(raw)
    except RecursionError:  # not reached below MAX_DEPTH; kept as a guard
        raise JSONTooDeepError(f"JSON nested too deep for the parser ({depth})") from None
