"""The simulated transmitters themselves: tension feed statistics, the pty endpoint, and the
standalone process (``python -m cdcr_ctl.sim.loadcells``) read by the real reader."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cdcr_ctl.config.loadcells import ModbusRegisterMap
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import G_M_PER_S2
from cdcr_ctl.sensors.loadcell_ascii import AsciiLoadCellStream
from cdcr_ctl.sensors.loadcell_modbus import ModbusLoadCellBus
from cdcr_ctl.sim.loadcells import (
    CAPACITY_N,
    AsciiLoadCellSim,
    ModbusLoadCellSim,
    PtyEndpoint,
    SensorNoise,
    TensionFeed,
)

ROOT = Path(__file__).resolve().parents[2]
KG = G_M_PER_S2


class ManualClock:
    def __init__(self, t_s: float = 0.0) -> None:
        self.t_s = t_s

    def __call__(self) -> float:
        return self.t_s


def test_feed_adds_seeded_noise_linear_drift_and_dropouts():
    clock = ManualClock(0.0)
    noise = SensorNoise(noise_N=0.3, drift_N_per_s=[0.0, 0.5], dropout=0.25, seed=7)
    feed = TensionFeed(lambda: [10.0, -4.0], 2, noise, clock)
    got = [feed.measure(0) for _ in range(4000)]
    kept = np.array([g for g in got if g is not None])
    assert 0.22 < 1 - len(kept) / len(got) < 0.28  # dropout fraction
    assert kept.mean() == pytest.approx(10.0, abs=0.03)
    assert kept.std(ddof=1) == pytest.approx(0.3, rel=0.06)
    quiet = TensionFeed(lambda: [10.0, -4.0], 2, SensorNoise(drift_N_per_s=[0.0, 0.5]), clock)
    clock.t_s = 8.0
    assert quiet.measure(1) == pytest.approx(-4.0 + 0.5 * 8.0)
    assert quiet.measure(0) == 10.0


def test_same_seed_gives_the_same_readings():
    clock = ManualClock()
    noise = SensorNoise(noise_N=1.0, dropout=0.1, seed=11)
    a = TensionFeed(lambda: [1.0], 1, noise, clock)
    b = TensionFeed(lambda: [1.0], 1, noise, clock)
    assert [a.measure(0) for _ in range(100)] == [b.measure(0) for _ in range(100)]


def test_feed_checks_the_callback_length():
    feed = TensionFeed(lambda: [1.0], 2, SensorNoise(), ManualClock())
    with pytest.raises(ValueError, match="1 values for 2 cells"):
        feed.measure(0)


def test_transmitter_counts_saturate_on_overload_and_follow_the_register_map():
    grams16 = ModbusRegisterMap(value_type="int16", unit="g", decimals=0, decimals_register=None)
    sim = ModbusLoadCellSim(lambda: [0.0], (1,), grams16)
    try:
        assert sim.counts(1, 1.0 * KG) == 1000  # 1 kg = 1000 g
        assert sim.counts(1, -0.5 * KG) == -500
        assert sim.counts(1, 2 * CAPACITY_N) == 2**15 - 1  # overload: saturated
        assert sim.counts(1, -2 * CAPACITY_N) == -(2**15)
        assert sim.counts(1, 1.05 * CAPACITY_N) == 10500  # above capacity, not yet overload
    finally:
        sim.stop()
    big = ModbusLoadCellSim(lambda: [0.0], (1,), grams16, capacity_N=100 * KG)
    try:  # a value the int16 cannot hold below the overload threshold: clipped under the flag
        assert big.counts(1, 50 * KG) == 2**15 - 2
    finally:
        big.stop()


def test_pty_endpoint_links_drops_unread_data_and_hangs_up(tmp_path):
    link = tmp_path / "sub" / "loadcells"
    end = PtyEndpoint(link)
    try:
        assert link.is_symlink() and os.readlink(link) == end.path
        for _ in range(2000):  # nobody reads: the pty fills, writes must not block
            end.write(b"ST,GS,+  1.000kg\r\n" * 10)
        assert end.overflow_bytes > 0
    finally:
        end.release()
    assert not link.exists()
    end.write(b"after close")  # ignored
    assert end.read(10, 0.0) == b""


def test_ascii_disconnect_hook_fails_the_reader(open_serial):
    with AsciiLoadCellSim(lambda: [3.0], rate_hz=200.0) as sim:
        stream = AsciiLoadCellStream(open_serial(sim.path))
        while not stream.poll():
            pass
        sim.disconnect()
        with pytest.raises(SensorError, match="disconnected"):
            for _ in range(1000):
                stream.poll()


def _spawn(*args: str) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "cdcr_ctl.sim.loadcells", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    path = proc.stdout.readline().strip()
    return proc, path


def test_standalone_process_prints_its_pty_and_serves_until_sigterm(tmp_path, open_serial):
    link = tmp_path / "lc"
    proc, path = _spawn(
        "--slaves", "4", "5", "--tension-N", "3", "7", "--link", str(link), "--duration-s", "60"
    )
    try:
        assert path.startswith("/dev/pts/"), proc.stderr.read() if proc.poll() else path
        assert os.readlink(link) == path
        bus = ModbusLoadCellBus(
            open_serial(str(link)), [4, 5], ModbusRegisterMap(), response_timeout_s=1.0
        )
        got = [bus.read(0), bus.read(1)]
        assert [r.reading_N for r in got] == [
            pytest.approx(3.0, abs=0.005),
            pytest.approx(7.0, abs=0.005),
        ]
    finally:
        proc.send_signal(signal.SIGTERM)
        _out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert "stats SimStats(requests=2" in err
    assert not link.exists()


def test_standalone_process_takes_the_bus_from_a_rig_config(tmp_path, open_serial):
    link = tmp_path / "lc"
    proc, path = _spawn(
        "--rig",
        str(ROOT / "config" / "qi2023-sim.yaml"),
        "--link",
        str(link),
        "--tension-N",
        "4",
        "5",
        "6",
        "--duration-s",
        "60",
    )
    try:
        assert path.startswith("/dev/pts/"), proc.stderr.read() if proc.poll() else path
        bus = ModbusLoadCellBus(
            open_serial(path), [1, 2, 3], ModbusRegisterMap(), response_timeout_s=1.0
        )
        values = [bus.read(i).reading_N for i in range(3)]
        assert values == [pytest.approx(v, abs=0.005) for v in (4.0, 5.0, 6.0)]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.communicate(timeout=10)
    assert proc.returncode == 0


def test_command_line_options_reach_the_simulator():
    from cdcr_ctl.sim.loadcells import _parser, build_sim

    args = _parser().parse_args(
        [
            "--slaves",
            "7",
            "8",
            "--tension-N",
            "1",
            "2",
            "--noise-N",
            "0.1",
            "--drift-N-per-s",
            "0.2",
            "--dropout",
            "0.3",
            "--seed",
            "9",
            "--baudrate",
            "9600",
            "--silence-s",
            "0.01",
            "--turnaround-s",
            "0.002",
            "--no-baud-emulation",
        ]
    )
    sim = build_sim(args)
    try:
        assert isinstance(sim, ModbusLoadCellSim) and sim.slaves == (7, 8)
        assert (sim.silence_s, sim.turnaround_s, sim.baudrate, sim.emulate_baud) == (
            0.01,
            0.002,
            9600,
            False,
        )
        assert sim.feed.noise == SensorNoise(0.1, 0.2, 0.3, 9)
        assert list(sim.feed.tensions()) == [1.0, 2.0]
    finally:
        sim.stop()
    ascii_args = _parser().parse_args(
        ["--protocol", "ascii", "--rate-hz", "50", "--tension-N", "3"]
    )
    sim = build_sim(ascii_args)
    try:
        assert isinstance(sim, AsciiLoadCellSim) and sim.rate_hz == 50.0
        assert list(sim.feed.tensions()) == [3.0]
    finally:
        sim.stop()
    with pytest.raises(SystemExit):
        build_sim(_parser().parse_args(["--tension-N", "1", "2"]))  # 3 default slaves


def test_sim_for_config_serves_what_the_config_reads(tmp_path):
    from cdcr_ctl.config.loadcells import LoadCellsConfig
    from cdcr_ctl.sensors.loadcell_sampler import open_load_cells
    from cdcr_ctl.sim.loadcells import sim_for_config

    link = tmp_path / "cells"
    lc = LoadCellsConfig.model_validate(
        {
            "serial": {"port": str(link), "timeout_s": 0.5},
            "register_map": {
                "value_type": "int16",
                "unit": "g",
                "decimals": 1,
                "decimals_register": None,
                "value_register": 5,
            },
            "cells": [{"cable": "a", "slave": 9}, {"cable": "b", "slave": 2}],
            "stale_after_s": 5.0,
        }
    )
    with sim_for_config(lc, lambda: [1.5, 2.5], link=lc.serial.port) as sim:
        assert isinstance(sim, ModbusLoadCellSim) and sim.slaves == (9, 2)
        with open_load_cells(lc) as cells:
            cells.wait_for_samples(1, timeout_s=5.0)
            got = [s.force_N for s in cells.latest()]
    # 0.1 g resolution = 0.00098 N: the reading is the truth to within half of that
    assert got == [pytest.approx(1.5, abs=0.0005), pytest.approx(2.5, abs=0.0005)]
    one = lc.model_copy(update={"protocol": "ascii", "cells": lc.cells[:1]})
    sim = sim_for_config(one, lambda: [1.0])
    try:
        assert isinstance(sim, AsciiLoadCellSim) and sim.unit == "g"
    finally:
        sim.stop()


def test_a_repeated_read_request_is_answered_with_the_value_of_now():
    """The transmitter keeps read requests it decoded (by frame bytes): the replies to the same
    frame still carry each moment's tension, and equal what a fresh transmitter answers; a
    write (tare) between them still acts."""
    from cdcr_ctl.sensors.loadcell_modbus import build_read_request, build_write_request, plan_read

    rm = ModbusRegisterMap(tare_register=4)
    force = [1.0, 2.0]
    kept = ModbusLoadCellSim(lambda: list(force), (1, 2), rm, emulate_baud=False)
    try:
        request = build_read_request(2, plan_read(rm))
        replies = []
        for f in (1.5, 2.5, 2.5, -0.75):
            force[1] = f
            fresh = ModbusLoadCellSim(lambda: list(force), (1, 2), rm, emulate_baud=False)
            try:
                expected = fresh.handle_bytes(request, 0.0)
            finally:
                fresh.stop()
            got = kept.handle_bytes(request, 0.0)
            assert got == expected
            replies.append(got[0][0])
        assert replies[0] != replies[1] == replies[2] != replies[3]
        assert len(kept._reads) == 1  # decoded once
        kept.handle_bytes(build_write_request(2, rm.tare_register, rm.tare_value), 0.0)
        assert kept.handle_bytes(request, 0.0) != replies[3]  # tared: reads ~0 now
        assert kept.stats.requests == 6
    finally:
        kept.stop()
