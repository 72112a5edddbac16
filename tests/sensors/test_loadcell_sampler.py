"""The sampling thread: ages and stale flags on an injected clock, failure handling, commands,
and building the reader from the config section."""

from __future__ import annotations

import math

import numpy as np
import pytest
import serial

from cdcr_ctl.config.loadcells import LoadCellsConfig
from cdcr_ctl.errors import RigTimeoutError, SensorError
from cdcr_ctl.sensors.loadcell import G_M_PER_S2, Calibration
from cdcr_ctl.sensors.loadcell_ascii import AsciiLoadCellStream, format_line
from cdcr_ctl.sensors.loadcell_modbus import ModbusLoadCellBus
from cdcr_ctl.sensors.loadcell_sampler import (
    LoadCellSampler,
    forces_and_ages,
    open_load_cells,
)
from cdcr_ctl.sim.loadcells import ModbusLoadCellSim

KG = G_M_PER_S2


class ManualClock:
    def __init__(self, t_s: float = 50.0) -> None:
        self.t_s = t_s

    def __call__(self) -> float:
        return self.t_s


def _loop_stream():
    """An ASCII stream over pyserial's loop:// port: bytes written come back as input."""
    port = serial.serial_for_url("loop://", timeout=0.01)
    return port, AsciiLoadCellStream(port, port_name="loop://")


def test_samples_carry_arrival_time_age_and_stale_flag():
    clock = ManualClock(50.0)
    port, stream = _loop_stream()
    cells = LoadCellSampler(
        stream, [Calibration(zero_N=1.0, span=2.0)], stale_after_s=0.1, clock=clock
    )
    (s,) = cells.latest()
    assert math.isnan(s.force_N) and s.age_s == math.inf and s.stale and s.seq == 0
    (f,), (a,) = cells.latest_forces()
    assert math.isnan(f) and a == math.inf
    with cells:
        port.write(format_line(1.0))  # 1 kg
        cells.wait_for_samples(1, timeout_s=5.0)
        (s,) = cells.latest(now_s=50.05)
        assert (s.t_s, s.age_s, s.stale, s.seq) == (50.0, pytest.approx(0.05), False, 1)
        assert s.reading_N == pytest.approx(KG)
        assert s.force_N == pytest.approx(2.0 * (KG - 1.0))  # span * (reading - zero)
        clock.t_s = 50.3
        (s,) = cells.latest()
        assert s.age_s == pytest.approx(0.3) and s.stale
        port.write(format_line(2.0))
        cells.wait_for_samples(2, timeout_s=5.0)
        (s,) = cells.latest()
        assert (s.t_s, s.age_s, s.stale) == (50.3, 0.0, False)
        forces, ages = forces_and_ages(cells.latest())
        assert forces.tolist() == [pytest.approx(2.0 * (2 * KG - 1.0))] and ages.tolist() == [0.0]
        # The loop's read: the same force and age, exactly
        clock.t_s = 50.4
        assert cells.latest_forces() == (
            [s.force_N for s in cells.latest()],
            [s.age_s for s in cells.latest()],
        )
    assert not cells.running and not port.is_open


def test_software_zero_and_calibration_changes_apply_to_the_latest_sample():
    port, stream = _loop_stream()
    with LoadCellSampler(stream, stale_after_s=5.0) as cells:
        with pytest.raises(SensorError, match="no fresh sample"):
            cells.zero(0)
        port.write(format_line(0.3))
        cells.wait_for_samples(1, timeout_s=5.0)
        cal = cells.zero(0)
        assert cal.zero_N == pytest.approx(0.3 * KG)
        assert cells.latest()[0].force_N == pytest.approx(0.0)
        cells.set_calibration(0, Calibration(zero_N=0.0, span=0.5))
        assert cells.latest()[0].force_N == pytest.approx(0.15 * KG)
        assert cells.calibration(0).span == 0.5


def test_port_failure_stops_the_sampler_and_flags_samples_stale():
    port, stream = _loop_stream()
    with LoadCellSampler(stream, stale_after_s=5.0) as cells:
        port.write(format_line(0.5))
        cells.wait_for_samples(1, timeout_s=5.0)
        port.close()  # the next read fails: port not open
        with pytest.raises(SensorError) as info:
            cells.wait_for_samples(10**9, timeout_s=5.0)
        assert info.value.port == "loop://"
        assert cells.failure is info.value
        (s,) = cells.latest()
        assert s.stale and s.force_N == pytest.approx(0.5 * KG)  # last value kept, flagged
        with pytest.raises(SensorError):
            cells.raise_if_failed()
        with pytest.raises(SensorError):
            cells.tare(0)


def test_waiting_for_samples_that_never_come_times_out():
    _port, stream = _loop_stream()
    with LoadCellSampler(stream) as cells, pytest.raises(RigTimeoutError, match="loop://"):
        cells.wait_for_samples(1, timeout_s=0.05)


def test_calibrations_must_match_the_cells():
    _port, stream = _loop_stream()
    with pytest.raises(ValueError):
        LoadCellSampler(stream, [Calibration(), Calibration()])


def _cfg(**over):
    data = {
        "protocol": "modbus_rtu",
        "serial": {"port": "/dev/null-not-a-port", "baudrate": 115200, "timeout_s": 0.2},
        "cells": [
            {"cable": "c1", "slave": 3, "zero_N": 0.5},
            {"cable": "c2", "slave": 1, "span": 1.5},
        ],
        "stale_after_s": 2.0,
    }
    data.update(over)
    return LoadCellsConfig.model_validate(data)


def test_open_load_cells_from_the_config_section_reads_the_simulator():
    truth = [10.0, 20.0]
    with ModbusLoadCellSim(lambda: truth, (3, 1)) as sim:
        cfg = _cfg(serial={"port": sim.path, "baudrate": 115200, "timeout_s": 0.2})
        with open_load_cells(cfg) as cells:
            assert isinstance(cells.link, ModbusLoadCellBus)
            cells.wait_for_samples(1, timeout_s=5.0)
            a, b = cells.latest()
            assert (a.address, b.address) == (3, 1)
            assert a.force_N == pytest.approx(10.0 - 0.5, abs=0.005)
            assert b.force_N == pytest.approx(1.5 * 20.0, abs=0.01)


def test_open_load_cells_errors_name_the_port():
    with pytest.raises(SensorError) as info:
        open_load_cells(_cfg())
    assert info.value.port == "/dev/null-not-a-port"
    port = serial.serial_for_url("loop://")
    with pytest.raises(SensorError, match="one cell"):
        open_load_cells(_cfg(protocol="ascii"), port=port)
    one = _cfg(protocol="ascii", cells=[{"cable": "c1"}])
    cells = open_load_cells(one, port=port)
    assert isinstance(cells.link, AsciiLoadCellStream) and cells.n_cells == 1
    cells.close()


def test_forces_and_ages_of_cells_without_samples():
    _port, stream = _loop_stream()
    forces, ages = forces_and_ages(LoadCellSampler(stream).latest())
    assert np.isnan(forces).all() and np.isinf(ages).all()
