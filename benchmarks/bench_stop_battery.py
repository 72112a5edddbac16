"""Issue #21's full battery: while a trajectory runs at 1 kHz on the simulated rig, send 16 MB
and 100 MB requests, a 10^6-row trajectory file, 200 concurrent clients, a slow client and
tiny-speed jogs, with ``stop`` in the middle of each; print, per stressor, the stop's delay in
loop cycles, the loop's long cycles and missed deadlines, and the lateness histogram.

Run: ``nice -n 5 .venv/bin/python benchmarks/bench_stop_battery.py [RATE_HZ]`` (about 3
minutes; RATE_HZ 1000 by default: the loop and the SYNC period of the session's rig config are
set to it, the shipped simulated rig runs 250 Hz).
How measured: the stop's reply names the loop cycle that sent the quick stop (the loop's stop
flag, :class:`cdcr_ctl.control.loop.StopFlag`) and ``cycles_waited`` counts loop cycles from the
request to it; long cycles and missed deadlines are the loop's own counters in ``status``
(``loop.long_cycles``, ``loop.missed_cycles``), lateness the loop's histogram (cumulative over
the daemon's life, printed after each stressor).
"""

from __future__ import annotations

import contextlib
import sys
import tempfile
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "system"))

from battery import (  # noqa: E402
    big_request,
    file_trajectory,
    idle,
    many_clients,
    recover,
    run_one,
    slow_client,
    tiny_jog,
)
from syshelp import session, start_daemon, start_sim, wait_for_socket  # noqa: E402


def _set_rate(rig: Path, rate_hz: float) -> None:
    doc = yaml.safe_load(rig.read_text())
    doc.setdefault("control", {})["rate_hz"] = rate_hz
    doc.setdefault("can", {})["sync_period_s"] = 1.0 / rate_hz
    rig.write_text(yaml.safe_dump(doc, sort_keys=False))


def main() -> None:
    rate_hz = float(sys.argv[1]) if len(sys.argv) > 1 else 1000.0
    tmp = Path(tempfile.mkdtemp(prefix="cdcr-battery-"))
    stressors = [
        ("baseline (nothing)", idle(2.0), 1.0),
        ("16 MB request", big_request(16 * 1024 * 1024), 0.3),
        ("100 MB request", big_request(100 * 1024 * 1024), 1.0),
        ("10^6-row file", file_trajectory(1_000_000, tmp), 2.0),
        ("200 clients", many_clients(200), 0.3),
        ("slow client (5 s)", slow_client(5.0), 2.0),
        ("jog speed 1e-4", tiny_jog(1e-4), 0.05),
        ("jog speed 1e-300", tiny_jog(1e-300), 0.05),
    ]
    with (
        session(tmp) as (work, rig, sim, _runs),
        start_sim(sim, tmp / "sim.log"),
        _with_rate(rig, rate_hz),
        start_daemon(rig, tmp / "d.log") as d,
    ):
        wait_for_socket(work / "control.sock", d, tmp / "d.log")
        print(f"loop and SYNC at {rate_hz:g} Hz")
        print(
            f"{'stressor':20s} {'stop cycles':>11s} {'window s':>8s} {'cycles':>7s}"
            f" {'long':>5s} {'missed':>6s} {'missed %':>8s}  reply"
        )
        last = None
        for name, fn, after_s in stressors:
            rec = run_one(work, name, fn, after_s)
            share = rec["missed_cycles"] / max(rec["cycles"] + rec["missed_cycles"], 1)
            print(
                f"{name:20s} {rec['cycles_waited']!s:>11s} {rec['window_s']:8.1f}"
                f" {rec['cycles']:7d} {rec['long_cycles']:5d} {rec['missed_cycles']:6d}"
                f" {100 * share:7.1f}%  {rec['reply'][:70]!r}"
                + (f"  DRIVE FAULTS {rec['drive_faults']}" if rec["drive_faults"] else "")
            )
            last = rec
            recover(work)
        print("lateness histogram of the loop over the whole battery (us: cycles):")
        for k, v in (last or {}).get("lateness_histogram", {}).items():
            print(f"  {k:>16s}: {v}")
        print(f"lateness max: {(last or {}).get('lateness_max_us')} us")


@contextlib.contextmanager
def _with_rate(rig: Path, rate_hz: float):
    _set_rate(rig, rate_hz)
    yield


if __name__ == "__main__":
    main()
