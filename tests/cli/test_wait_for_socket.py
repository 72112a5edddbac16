"""``wait_for_socket`` (cdcr_ctl/cli/demo.py): past its timeout a starting daemon is waited for
as long as its processes use CPU (slow, not stuck); one that uses none is given up on."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from cdcr_ctl.cli import demo
from cdcr_ctl.errors import RigError


def _start(code: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code])


def test_a_busy_start_is_waited_for_and_an_idle_one_given_up(tmp_path, monkeypatch):
    monkeypatch.setattr(demo, "START_TIMEOUT_S", 0.2)
    monkeypatch.setattr(demo, "START_STALL_S", 1.0)  # loaded, a process may starve 0.6 s
    sock = tmp_path / "none.sock"
    # Busy for 2 s, then gone: waited for until it exits.
    busy = _start("import time\nt = time.monotonic()\nwhile time.monotonic() - t < 2.0: pass")
    t0 = time.monotonic()
    with pytest.raises(RigError, match="daemon exited with 0"):
        demo.wait_for_socket(sock, busy, tmp_path / "log")
    assert time.monotonic() - t0 > 1.5
    # Asleep (no CPU): given up once START_STALL_S passed without progress, long before it ends.
    idle = _start("import time\ntime.sleep(30)")
    try:
        t0 = time.monotonic()
        with pytest.raises(RigError, match="did not open"):
            demo.wait_for_socket(sock, idle, tmp_path / "log")
        assert time.monotonic() - t0 < 15.0
    finally:
        idle.kill()
        idle.wait()
