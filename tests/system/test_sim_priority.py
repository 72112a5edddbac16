"""The simulated rig, started beside the daemon, runs at SIM_NICE (stand-in hardware), its
session's autogroup too where the kernel has one."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from cdcr_ctl.cli.demo import SIM_NICE, autogroup_nice, running


def test_running_sets_the_nice_level(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("a nice level below 0 needs root (or CAP_SYS_NICE, not probed here)")
    cmd = [sys.executable, "-c", "import time; print('ready', flush=True); time.sleep(30)"]
    with running(cmd, tmp_path / "p.log", ready="ready", nice=SIM_NICE) as proc:
        assert os.getpriority(os.PRIO_PROCESS, proc.pid) == SIM_NICE
        if Path(f"/proc/{proc.pid}/autogroup").exists():
            # Its session's share against other sessions', relative to this one's.
            assert autogroup_nice(proc.pid) == autogroup_nice() + SIM_NICE
    assert SIM_NICE < 0
