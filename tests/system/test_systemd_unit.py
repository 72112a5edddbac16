"""The systemd unit passes `systemd-analyze verify`, and its security exposure stays low."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parents[2] / "systemd" / "cdcr-ctl.service"
INSTALLED = "/opt/cdcr-ctl/.venv/bin/cdcr-ctl"

pytestmark = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed here"
)


def unit_here(tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at this checkout's cdcr-ctl (verify checks it exists)."""
    exe = Path(sys.executable).parent / "cdcr-ctl"
    text = UNIT.read_text()
    assert INSTALLED in text
    out = tmp_path / "cdcr-ctl.service"
    out.write_text(text.replace(INSTALLED, str(exe)))
    return out


def test_unit_verifies_clean(tmp_path):
    res = subprocess.run(
        ["systemd-analyze", "verify", str(unit_here(tmp_path))], capture_output=True, text=True
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "" and res.stderr.strip() == ""


def test_unit_is_notify_with_watchdog_and_keeps_devices():
    text = UNIT.read_text()
    for line in ("Type=notify", "Restart=on-failure", "RuntimeDirectory=cdcr-ctl", "LimitRTPRIO="):
        assert line in text
    assert re.search(r"^WatchdogSec=\d+", text, re.M)
    assert "PrivateDevices=" not in text
    assert "AF_CAN" in text


def test_security_exposure_is_low(tmp_path):
    res = subprocess.run(
        ["systemd-analyze", "security", "--offline=yes", str(unit_here(tmp_path))],
        capture_output=True,
        text=True,
    )
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", res.stdout)
    assert m, res.stdout[-500:] + res.stderr[-500:]
    assert float(m.group(1)) < 3.0


#: The scheduling calls the daemon's processes make: the loop (SCHED_FIFO), its memory lock, the
#: run-log writer (SCHED_BATCH, nice) and the intake worker (nice).
SCHEDULING_CALLS = ("sched_setscheduler", "sched_setparam", "mlockall", "setrlimit", "setpriority")


def test_scheduling_calls_survive_the_syscall_filter():
    """A call in a denied group (``~@resources``) kills the process with SIGSYS unless a later
    ``SystemCallFilter=`` line allows it by name (systemd.exec(5))."""
    res = subprocess.run(
        ["systemd-analyze", "syscall-filter", "@resources"], capture_output=True, text=True
    )
    resources = {w for w in res.stdout.split() if w.isidentifier()}
    assert "setpriority" in resources, res.stdout  # the group this test is about
    lines = re.findall(r"^SystemCallFilter=(.*)$", UNIT.read_text(), re.M)
    denied = [i for i, v in enumerate(lines) if v.startswith("~") and "@resources" in v]
    assert denied, lines
    allowed = {w for v in lines[denied[-1] + 1 :] if not v.startswith("~") for w in v.split()}
    for call in SCHEDULING_CALLS:
        assert call not in resources or call in allowed, (call, lines)
    assert re.search(r"^LimitNICE=\+0$", UNIT.read_text(), re.M)
