"""The three formulas kept in two forms, each form timed against the other (per call).

1. the disk weight sums of a segment (:func:`cdcr_ctl.model.cc_disk.transfer._disk_sums`, the ratios
   written out per disk) against the same sums through
   :func:`~cdcr_ctl.model.cc_disk.transfer._ratios` per disk, on the segment of the Qi et al. 2023
   rig (config/qi2023.yaml, its disks with their weights); they run for every segment in every
   evaluation of the gravity moments;
2. a pulley's fused ``to_actuator_stretch`` against ``to_actuator`` + ``stretch_integral`` (the
   two calls whose floats it gives), on the rig's table pulley (n = 0.67 law where the config
   has one, else its first pulley), tensions 0.5-40 N, pulled in and paid out;
3. the tip frame on plain floats (:func:`cdcr_ctl.model.cc_disk.kinematics.tip_frame_fast`) against
the
   last frame of :func:`~cdcr_ctl.model.cc_disk.kinematics.chain` (numpy), three segments.

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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cdcr_ctl.config import load_rig_config  # noqa: E402
from cdcr_ctl.config.build_model import robot_params  # noqa: E402
from cdcr_ctl.model.cc_disk import kinematics as kin  # noqa: E402
from cdcr_ctl.model.cc_disk.params import Effects  # noqa: E402
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, _disk_sums, _ratios  # noqa: E402

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
        ss1, cc2, dd1, dd2, _ = _ratios(sig * t)
        A += ms2 * cc2
        B += ms4 * dd2
        C += ms3 * dd1
        D += ms * ss1
    return A, B, C, D


def _pair(tr, T, s, T0):
    Tn = tr.to_actuator(T, s)
    return Tn, tr.stretch_integral(Tn, T, s, T0)


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
        race({"_disk_sums": _disk_sums, "_ratios per disk": _sums_by_ratios}, ts),
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
