"""The three formulas kept in two forms, each form timed against the other (per call), and the
cost of three hot formulas kept in one form.

1. the disk weight sums of a segment (:func:`cdcr_ctl.model.cc_disk.transfer._disk_sums`, the ratios
   written out per disk) against the same sums through the kinematics ratios
   (:func:`~cdcr_ctl.model.cc_disk.kinematics.s1`, ``c2``, ``d1``, ``d2``) per disk, on the
   segment of the Qi et al. 2023 rig (config/qi2023.yaml, its disks with their weights); they
   run for every segment in every evaluation of the gravity moments;
2. a pulley's fused ``to_actuator_stretch`` against ``to_actuator`` + ``stretch_integral`` (the
   two calls whose floats it gives), on the rig's table pulley (n = 0.67 law where the config
   has one, else its first pulley), tensions 0.5-40 N, pulled in and paid out;
3. the tip frame on plain floats (:func:`cdcr_ctl.model.cc_disk.kinematics.tip_frame_fast`) against
the
   last frame of :func:`~cdcr_ctl.model.cc_disk.kinematics.chain` (numpy), three segments;
4. one form each: a simulated EPOS4's CSP step of one SYNC (the config's interpolation period,
   1 ms: 4 sub-steps of :meth:`~cdcr_ctl.sim.epos.plant.Motor.substeps`, the rig's first drive,
   3 counts a SYNC), the loop's :meth:`~cdcr_ctl.control.loop.TipHistory.distance` (150 tips
   at 1 kHz, 52 in the window), and the five kinematics ratios of one segment's bend (the
   gravity moments of a robot of several segments call them once per segment).

How: ``time.perf_counter_ns`` around blocks of 200 calls at inputs that change every call,
after a warm-up; the median of 50 blocks per form, in us per call. The forms alternate block by
block, so a load that comes and goes hits both alike.

    .venv/bin/python benchmarks/bench_hot_paths.py
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from pathlib import Path

import canopen
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdcr_ctl.config import load_rig_config  # noqa: E402
from cdcr_ctl.config.build_model import robot_params  # noqa: E402
from cdcr_ctl.control.loop import TipHistory  # noqa: E402
from cdcr_ctl.drives import epos  # noqa: E402
from cdcr_ctl.drives.cia402 import Mode, State  # noqa: E402
from cdcr_ctl.model.cc_disk import kinematics as kin  # noqa: E402
from cdcr_ctl.model.cc_disk.params import Effects  # noqa: E402
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, _disk_sums  # noqa: E402
from cdcr_ctl.sim.epos.node import SimEpos  # noqa: E402
from cdcr_ctl.sim.epos.plant import MotorParams  # noqa: E402

BLOCK, BLOCKS = 200, 50


def race(forms: dict[str, object], inputs: list[tuple]) -> dict[str, float]:
    """Median us per call of each form over the inputs, blocks alternating between forms."""
    per: dict[str, list[float]] = {name: [] for name in forms}
    for _ in range(3):  # warm-up
        for fn in forms.values():
            for args in inputs[:BLOCK]:
                fn(*args)
    for b in range(BLOCKS):
        chunk = inputs[(b * BLOCK) % len(inputs) :][:BLOCK]
        for name, fn in forms.items():
            t0 = time.perf_counter_ns()
            for args in chunk:
                fn(*args)
            per[name].append((time.perf_counter_ns() - t0) / 1e3 / len(chunk))
    return {name: statistics.median(v) for name, v in per.items()}


def _sums_by_ratios(disks, t):
    A = B = C = D = 0.0
    for sig, ms2, ms3, ms4, ms in disks:
        st = sig * t
        ss1, cc2, dd1, dd2 = kin.s1(st), kin.c2(st), kin.d1(st), kin.d2(st)
        A += ms2 * cc2
        B += ms4 * dd2
        C += ms3 * dd1
        D += ms * ss1
    return A, B, C, D


def _pair(tr, T, s, T0):
    Tn = tr.to_actuator(T, s)
    return Tn, tr.stretch_integral(Tn, T, s, T0)


def _csp_drive(cfg):
    """The rig's first drive, simulated, enabled in CSP (no bus: stepped here only)."""
    d = cfg.drives[0]
    n = SimEpos(canopen.Network(), 1, d.type, MotorParams(counts_per_rev=d.encoder_counts_per_rev))
    for w in epos.configuration_writes(d, cfg.can):
        if w.index != epos.HEARTBEAT_PRODUCER:
            n.node.set_data(w.index, w.sub, w.data, check_writable=True)
    n.advance_on_sync = False
    n.force_state(State.OPERATION_ENABLED, mode=Mode.CYCLIC_SYNC_POSITION)
    n.load_torque_Nm = -0.15
    return n


def _sync(n, dt):
    n._csp_from = n.profile.x  # the next segment: 3 counts on
    n._csp_to, n._csp_t = n._csp_from + 3.0, 0.0
    n.step(dt)


def _five_ratios(t):
    return kin.s1(t), kin.c2(t), kin.d1(t), kin.d2(t), kin.e2(t)


def one_form(cfg) -> dict[str, float]:
    """Median us per call of the formulas kept in one form (section 4 of the docstring)."""
    n = _csp_drive(cfg)
    period = n.interpolation_period_s
    got = race({f"CSP step of {period * 1e3:g} ms (sub-steps)": _sync}, [(n, period)] * BLOCK)
    tips = TipHistory(150)
    for k in range(2000):
        t = k * 0.001
        tips.add(t, [30.0 * math.sin(t), 10.0 * math.cos(t), 300.0])
    args = [(1.999, [1.0, 2.0, 300.0], 0.008 + 1e-5 * j, 0.05, 0.001) for j in range(BLOCK)]
    got |= race({"TipHistory.distance": tips.distance}, args)
    ratios = [(0.05 + 1.5 * j / 997,) for j in range(997)]
    got |= race({"s1, c2, d1, d2, e2 of one bend": _five_ratios}, ratios)
    return got


def show(title: str, got: dict[str, float]) -> None:
    (a, ta), (b, tb) = got.items()
    print(f"{title}\n  {a}: {ta:.2f} us/call\n  {b}: {tb:.2f} us/call ({tb / ta:.2f} x)")


def main() -> int:
    cfg = load_rig_config(ROOT / "config" / "qi2023.yaml")
    ft = ForceTransfer(robot_params(cfg.robot), Effects(geometry=cfg.control.geometry))
    disks = ft._disk_w[0]
    ts = [(disks, 0.05 + 1.5 * j / 997) for j in range(997)]
    show(
        f"1. disk weight sums, one segment of {len(disks)} disks",
        race({"_disk_sums": _disk_sums, "kinematics ratios per disk": _sums_by_ratios}, ts),
    )
    pulleys = [tr for k in range(ft.K) for tr in ft.pulleys(k)]
    tr = next((p for p in pulleys if not p.constant), pulleys[0])
    args = [(tr, 0.5 + 39.5 * (j % 101) / 100, (1.0, -1.0, 0.4)[j % 3], 2.0) for j in range(1000)]
    show(
        "2. pulley: tension to the actuator side and the stretch over the wrap",
        race(
            {
                "to_actuator_stretch": lambda tr, T, s, T0: tr.to_actuator_stretch(T, s, T0),
                "to_actuator + stretch_integral": _pair,
            },
            args,
        ),
    )
    lengths = [90.0, 80.0, 70.0]
    psis = []
    for j in range(1000):
        a = 2.0 * math.pi * j / 1000
        psis.append(np.array([[0.6 + 0.2 * math.sin(a), a], [0.5, a + 1.0], [0.7, -a]]))
    xs = [(kin.psi_to_x(p).ravel().tolist(), lengths) for p in psis]
    chain_args = [(p, np.array(lengths)) for p in psis]
    got = race({"tip_frame_fast": kin.tip_frame_fast}, xs)
    got |= race({"chain()[-1]": lambda p, L: kin.chain(p, L)[-1]}, chain_args)
    show("3. tip frame of three segments", got)
    print("4. one form each")
    for name, us in one_form(cfg).items():
        print(f"  {name}: {us:.2f} us/call")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
