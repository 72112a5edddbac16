"""Waiting for a writer thread or process in the run-log tests."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(pred: Callable[[], object], timeout_s: float, poll_s: float) -> bool:
    """Poll ``pred`` every ``poll_s`` until it holds or ``timeout_s`` passed; its last value."""
    end = time.monotonic() + timeout_s
    while not pred() and time.monotonic() < end:
        time.sleep(poll_s)
    return bool(pred())
