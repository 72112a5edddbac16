"""Fault diagnosis: after a fault the group reads the drive's 0x603F and 0x1003 and shows them
with the fault; abort codes print with all eight digits."""

from __future__ import annotations

import struct
import time

import pytest
from drivesim import Cycler, drive_cfgs, make_rig, wait_until

from cdcr_ctl.drives.diagnosis import Diagnosis, history_text
from cdcr_ctl.errors import DriveFault


def test_history_entries_as_text():
    assert history_text([0x8611, 0x0001_2310], "epos4") == [
        "0x8611 following error",
        "0x2310 over-current error (info 0x0001)",
    ]
    d = Diagnosis(2, 0x8611, (0x8611,), "epos4")
    assert d.text == "0x603F 0x8611 following error; 0x1003 0x8611 following error"
    assert Diagnosis(1, None, (), "epos2", "reading stopped: x").text == "reading stopped: x"


def test_abort_code_prints_eight_hex_digits():
    assert str(DriveFault(2, 0x06090011, "SDO write refused")).startswith("node 2: 0x06090011 ")
    assert str(DriveFault(2, 0x8611, "following error")).startswith("node 2: 0x8611 ")


@pytest.mark.parametrize("kind", ["epos4", "epos2"])
def test_fault_shows_the_drives_error_code_and_history(kind):
    mode = "csp" if kind == "epos4" else "pm"
    r = make_rig(drive_cfgs(2, kind, mode), sync_period_s=0.002 if kind == "epos4" else 0.005)
    g = r.group
    try:
        with Cycler(g):
            r.sim.node(2).inject_over_current()  # an older entry in the history
            assert wait_until(lambda: g.fault() is not None and g.fault().diagnosis)
            assert wait_until(lambda: r.sim.node(2).state.name == "FAULT")
            time.sleep(0.05)
            g.reset_faults(timeout_s=2.0)
            g.enable()
            r.sim.node(2).inject_following_error()
            assert wait_until(lambda: g.fault() is not None and g.fault().diagnosis)
        f = g.fault()
        if kind == "epos4":
            assert f.diagnosis.startswith("0x603F 0x8611 following error; ")
        else:
            assert "0x603F" not in f.diagnosis  # the EPOS2 has none
        assert "0x1003 0x8611 following error, 0x2310 over-current error" in f.diagnosis
        assert f.text.endswith(f"[{f.diagnosis}]")
        with pytest.raises(DriveFault) as exc:
            g.raise_if_faulted()
        assert any(f.diagnosis in note for note in exc.value.__notes__)
        assert r.sim.node(2).node.data_store[0x1003][1] == struct.pack("<I", 0x8611)
    finally:
        r.close()
