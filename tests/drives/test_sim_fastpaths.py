"""The simulated EPOS's fast path of the steady CSP cycle's target RPDO (written without the
generic checks) against the general path (``fast_paths = False``: every write through canopen's
callbacks and the limits check): two nodes fed the same frames give the same frames back and
the same state, bit for bit, SYNC after SYNC, through steady motion, current saturation, missed
set-points, halt, quick stop, software-limit and following-error faults with their resets, a
short RPDO, NMT stop/start, a feedback lag of 2, an extra write callback and a load function.
The rewritten statusword against the one it replaced; the CSP sub-steps' safe box against the
exact comparisons it stands for, and the sub-steps against the motor's equations worked by
hand."""

from __future__ import annotations

import math
import random
import struct
from pathlib import Path

import can
import canopen
import pytest

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.drives import cia402 as c
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.cia402 import Mode, State
from cdcr_ctl.drives.emcy import FOLLOWING_ERROR, PDO_LENGTH_ERROR, SOFTWARE_LIMIT
from cdcr_ctl.sim.epos.node import SimEpos
from cdcr_ctl.sim.epos.plant import MotorParams
from cdcr_ctl.sim.epos.stepping import safe_box
from cdcr_ctl.sim.simconfig import load_sim_config

ROOT = Path(__file__).resolve().parents[2]


class _Recorder(can.BusABC):
    """A bus that keeps every frame sent on it and receives nothing."""

    def __init__(self) -> None:
        self.sent: list[tuple[int, bytes]] = []
        super().__init__(channel="recorder")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append((msg.arbitration_id, bytes(msg.data)))

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:
        return None, False


def _node(fast: bool) -> tuple[SimEpos, _Recorder]:
    """A node configured like the Qi rig's first drive, on a network of its own."""
    loaded = load_sim_config(ROOT / "config" / "sim" / "qi2023-truth-clean.yaml")
    ctl = load_rig_config(loaded.rig_path)
    d = ctl.drives[0]
    bus = _Recorder()
    n = SimEpos(
        canopen.Network(bus), 1, d.type, MotorParams(counts_per_rev=d.encoder_counts_per_rev)
    )
    n.fast_paths = fast
    for w in epos.configuration_writes(d, ctl.can):
        if w.index == epos.HEARTBEAT_PRODUCER:
            continue  # no heartbeat thread in this test
        n.node.set_data(w.index, w.sub, w.data, check_writable=True)
    n.sync_period_s = 0.004
    n.load_torque_Nm = -0.15
    n._rebuild_pdos()  # the new mapping (the first SYNC would do it)
    return n, bus


def target_frame(cob: int, counts: int) -> tuple[int, bytes]:
    return cob, struct.pack("<i", counts)


def _bits(value: object) -> object:
    """Floats by their bits (-0.0 is not 0.0 here), containers element by element."""
    if isinstance(value, float):
        return value.hex()
    if isinstance(value, dict):
        return {k: _bits(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_bits(v) for v in value]
    return value


def _snapshot(n: SimEpos) -> object:
    m, p = n.motor, n.profile
    return _bits(
        (
            m.x, m.v, m.i, m._integral, p.x, p.v, p.a, n._csp_t, n._csp_from, n._csp_to,
            n.max_following_error_counts, n.following_error, n._ferr_s, n.state, n.mode,
            n.controlword, n.internal_limit, n.error_code, n.error_register, n.offset,
            n.sync_count, n.rpdo_count, n.missed_setpoints, n.emcy_sent, n._params,
            n.node.data_store, n.last_target, n.last_target_change[1],
            [(c, s) for _, c, s in n.transitions], list(n._samples), n._setpoint_since_sync,
            n.statusword, n.position_counts, n.node.nmt.state,
        )
    )  # fmt: skip


#: A target this many counts from the present demand (resolved when its SYNC comes).
Rel = tuple[str, int]


def _script(cob_target: int, cob_cw: int) -> list[list[tuple[int, bytes] | Rel]]:
    """Frames before each SYNC (the SYNC itself is added by the test)."""

    def target(counts: int) -> tuple[int, bytes]:
        return cob_target, struct.pack("<i", counts)

    def cw(word: int) -> tuple[int, bytes]:
        return cob_cw, struct.pack("<H", word)

    def ramp(n: int, step: int = 3) -> list[list[tuple[int, bytes] | Rel]]:
        return [[("rel", step)] for _ in range(n)]

    enable: list[list[tuple[int, bytes] | Rel]] = [[cw(0x06)], [cw(0x07)], [cw(0x0F)]]
    steps: list[list[tuple[int, bytes] | Rel]] = [[(0x000, bytes((0x01, 1)))], *enable]
    steps += [[target(3 * k)] for k in range(40)]  # steady ramp
    steps += [[target(6000)]] * 6 + [[target(120)]] * 6  # current saturation and back
    steps += [[], [], [target(150)]]  # two missed set-points (the segment held at its end)
    steps += [[cw(0x10F), target(400)], [target(500)], [cw(0x0F)], [target(520)]]  # halt
    steps += [[cw(0x02)]] + [[]] * 40 + enable + ramp(5)  # quick stop, enable
    steps += [[("rel", 60_000)]] * 3 + [[cw(0x80)]] + enable + ramp(5)  # following error
    steps += [[target(2_100_000_000)], [cw(0x80)], *enable, *ramp(5)]  # software limit
    steps += [[(cob_target, b"\x01\x02")], [cw(0x80)], *enable]  # short RPDO: fault
    steps += ramp(10) + ramp(6, -40)
    steps += [[(0x000, bytes((0x02, 1))), ("rel", 3)], [("rel", 3)]]  # NMT stop
    steps += [[(0x000, bytes((0x01, 1))), ("rel", 3)], *ramp(8)]  # and start
    steps += ramp(10)  # (k >= 140: a load function)
    return steps


@pytest.mark.timeout(120)
def test_fast_paths_agree_bit_for_bit_with_the_general_paths():
    fast, fast_bus = _node(True)
    general, general_bus = _node(False)
    taken = {"target": 0}
    write_target = fast._write_target

    def counting_write_target(plan: tuple, data: bytes) -> bool:
        done = write_target(plan, data)
        taken["target"] += done
        return done

    fast._write_target = counting_write_target  # type: ignore[method-assign]
    cob_target = next(c for c, p in fast._rpdos.items() if p.entries[0][0] == epos.TARGET_POSITION)
    cob_cw = next(c for c, p in fast._rpdos.items() if p.entries[0][0] == epos.CONTROLWORD)
    for n in (fast, general):
        n.node.set_data(epos.MODES_OF_OPERATION, 0, bytes((Mode.CYCLIC_SYNC_POSITION,)))
        n.node.set_data(epos.SOFTWARE_POSITION_LIMIT, 2, struct.pack("<i", 2_000_000_000))
    script = _script(cob_target, cob_cw)
    for k, frames in enumerate(script):
        if k == 20:  # a feedback lag of 2 for a while (in the steady ramp)
            fast.lag_cycles = general.lag_cycles = 2
        if k == 30:
            fast.lag_cycles = general.lag_cycles = 1
        if k == 120:  # another write callback: the target's fast path must step aside
            for n in (fast, general):
                n.node.add_write_callback(lambda **kw: None)
        if k == 140:  # a load function: the torque from the state, one sub-step at a time
            for n in (fast, general):
                n.load_fn = lambda x, v: -0.1 - 1e-6 * v
        demand = round(fast.profile.x + fast.offset)
        resolved = [target_frame(cob_target, demand + f[1]) if f[0] == "rel" else f for f in frames]
        for n in (fast, general):
            for cob, data in [*resolved, (0x080, b"")]:
                n.network.notify(cob, bytearray(data), 0.0)
        assert _snapshot(fast) == _snapshot(general), (k, frames)
        assert fast_bus.sent == general_bus.sent, k
    fast_bus.shutdown()
    general_bus.shutdown()
    assert taken["target"] > 50
    assert {State.FAULT, State.QUICK_STOP_ACTIVE} <= {s for _, _, s in fast.transitions}
    assert {FOLLOWING_ERROR, PDO_LENGTH_ERROR, SOFTWARE_LIMIT["epos4"]} <= set(fast.emcy_sent)
    assert fast.state is State.OPERATION_ENABLED and fast.lag_cycles == 1


def _statusword_before(n: SimEpos) -> int:
    """The statusword by the rules ``objects.py`` followed before the rewrite (a reference):
    each bit with the condition that sets it."""
    s, mode, phase = n.state, n.mode, n._homing_phase
    homing = mode == Mode.HOMING
    positioning = (
        Mode.CYCLIC_SYNC_POSITION,
        Mode.PROFILE_POSITION,
        Mode.POSITION_MODE,
        Mode.INTERPOLATED_POSITION,
    )
    powered = (State.READY_TO_SWITCH_ON, State.SWITCHED_ON)
    rules = [
        (c.SW_REMOTE, True),
        (c.SW_VOLTAGE_ENABLED, s in (*powered, State.OPERATION_ENABLED, State.QUICK_STOP_ACTIVE)),
        (c.SW_HOMING_ATTAINED | c.SW_TARGET_REACHED, homing and phase == "done"),
        (c.SW_HOMING_ERROR, homing and phase == "error"),
        (c.SW_TARGET_REACHED, not homing and n._at_target()),
        (c.SW_SETPOINT_ACK, mode == Mode.PROFILE_POSITION and n._setpoint_ack),
        (c.SW_IP_ACTIVE, mode == Mode.INTERPOLATED_POSITION and n.pvt.active),
        (
            c.SW_FOLLOWING_COMMAND,
            mode == Mode.CYCLIC_SYNC_POSITION and s is State.OPERATION_ENABLED,
        ),
        (c.SW_FOLLOWING_ERROR, mode in positioning and n.following_error),
        (c.SW_INTERNAL_LIMIT, n.internal_limit),
        (c.SW_POSITION_REFERENCED, n._homed and n.kind == "epos4"),
    ]
    sw = c.STATE_BITS.get(s, 0)
    for bit, condition in rules:
        if condition:
            sw |= bit
    return sw


@pytest.mark.parametrize("kind", ["epos4", "epos2"])
def test_statusword_as_before_in_every_state_mode_and_flag(kind):
    n = SimEpos(canopen.Network(), 1, kind)
    modes = [0, 1, 3, 6, 7, 8, 9, 10, -1]
    for state in State:
        for mode in modes:
            for flags in range(128):
                n._state = state
                n.mode = mode
                n.following_error = bool(flags & 1)
                n.internal_limit = bool(flags & 2)
                n._homed = bool(flags & 4)
                n._setpoint_ack = bool(flags & 8)
                n.pvt.active = bool(flags & 16)
                n._homing_phase = ("done", "error", "")[flags % 3]
                n.profile.v = 0.0 if flags & 32 else 5.0
                n.motor.x = 10.0 if flags & 64 else 1.0  # the position window is 4 counts
                assert n.statusword == _statusword_before(n), (state, mode, flags)


def test_safe_box_is_sufficient_for_the_exact_position_checks():
    rng = random.Random(7)
    cases = [(-2_147_483_649, 2_147_483_648), (-1001, 1001), (-2_000_001, 2_000_001)]
    for lo1, hi1 in cases:
        for _ in range(2000):
            offset = rng.choice([0.0, rng.uniform(-1e9, 1e9), rng.uniform(-5, 5)])
            sw_lo, sw_hi = rng.choice([(-math.inf, math.inf), (-5000.5, 5000.5)])
            xmin, xmax = safe_box(lo1, hi1, offset, sw_lo, sw_hi)
            for edge in (xmin, xmax):
                if not math.isfinite(edge):
                    continue
                for x in (edge, math.nextafter(edge, 0.0), math.nextafter(edge, math.inf) + 0.0):
                    x = x + rng.choice([0.0, 1e-9, -1e-9])
                    if xmin < x < xmax:
                        assert lo1 <= x + offset <= hi1 and sw_lo < x < sw_hi
    assert safe_box(-10, 10, math.nan, -math.inf, math.inf) == (math.inf, -math.inf)
    assert safe_box(-10, 10, 2.0**41, -math.inf, math.inf) == (math.inf, -math.inf)


def test_csp_substeps_are_the_motor_equations_by_hand():
    # One drive in CSP, one SYNC of 4 ms = 16 sub-steps of 0.25 ms towards a target 40 counts
    # on; the same sub-steps worked out here from plant.py's equations (PID with feed-forward,
    # current limit, semi-implicit Euler, the reference on the straight line of the period).
    n, bus = _node(True)
    n.force_state(State.OPERATION_ENABLED, mode=Mode.CYCLIC_SYNC_POSITION)
    n._csp_from, n._csp_to, n._csp_t = 0.0, 40.0, 0.0
    n._step_period_s = 0.004
    p = n.motor.p
    k = 2 * math.pi / p.counts_per_rev
    w = 2 * math.pi * p.bandwidth_hz
    kp, kd, ki = 3 * w * w, 3 * w, w**3
    x = v = integral = t = 0.0
    xr = vr = 0.0
    h = 0.004 / 16
    for _ in range(16):
        e = xr - x
        i = p.inertia_kgm2 * k * (kp * e + kd * (vr - v) + ki * integral) / p.torque_constant_Nm_A
        if abs(i) >= p.current_limit_A:
            i = math.copysign(p.current_limit_A, i)
        else:
            integral += e * h
        torque = p.torque_constant_Nm_A * i + n.load_torque_Nm / p.gear_ratio
        torque -= p.viscous_Nm_s_rad * k * v
        v += torque / p.inertia_kgm2 / k * h
        x += v * h
        t = min(t + h, 0.004)
        xr, vr = 40.0 * t / 0.004, (10_000.0 if t < 0.004 else 0.0)
    assert n._csp_substeps(h, 16) == 16
    # the same operations in the same order but 40 t / 0.004 against (40 / 0.004) t: 1e-12
    assert (n.motor.x, n.motor.v, n.motor.i) == pytest.approx((x, v, i), rel=1e-12, abs=1e-12)
    assert (n.profile.x, n.profile.v) == pytest.approx((40.0, 0.0), abs=1e-12)
    assert n.state is State.OPERATION_ENABLED and not n.following_error
    bus.shutdown()
