"""Safety supervisor: each limit trips its defined reaction; trips latch and escalate."""

from __future__ import annotations

import math

from cdcr_ctl.config.control import LimitsConfig
from cdcr_ctl.control.supervisor import CycleCheck, Reaction, Supervisor

LIM = LimitsConfig(
    cable_displacement_mm=[-10.0, 10.0],
    cable_velocity_mm_s=20.0,
    tension_N=[0.5, 40.0],
    tracker_divergence_mm=15.0,
    sensor_timeout_s=0.2,
)


def check(**kw):
    base = dict(t_s=1.0, dt_s=0.001, q_cmd_mm=[0.0, 0.0, 0.0], q_prev_mm=[0.0, 0.0, 0.0])
    base.update(kw)
    return CycleCheck(**base)


def sup():
    return Supervisor(LIM, use_tension=True, use_tracker=True)


OK_T = dict(tension_N=[5.0, 5.0, 5.0], tension_age_s=[0.01] * 3, tip_error_mm=1.0, tip_age_s=0.01)


def test_nothing_trips_inside_limits():
    s = sup()
    assert s.check(check(**OK_T)) is None
    assert s.trip is None


def test_each_limit_has_its_reaction():
    cases = [
        (
            dict(q_cmd_mm=[10.5, 0, 0], q_prev_mm=[10.495, 0, 0]),
            "displacement_limit:cable1",
            Reaction.HOLD,
        ),
        (dict(q_cmd_mm=[0, 0.05, 0]), "velocity_limit:cable2", Reaction.HALT),  # 50 mm/s
        (dict(q_cmd_mm=[0, 0, math.nan]), "command_invalid:cable3", Reaction.HALT),
        (dict(tension_N=[5.0, 41.0, 5.0]), "tension_high:cable2", Reaction.QUICK_STOP),
        (dict(tension_N=[0.1, 5.0, 5.0]), "tension_low:cable1", Reaction.HOLD),
        (dict(tension_age_s=[0.01, 0.01, 0.5]), "stale_tension:cable3", Reaction.HALT),
        (dict(tip_error_mm=16.0), "tracker_divergence", Reaction.HALT),
        (dict(tip_age_s=math.inf), "stale_tracker", Reaction.HALT),
    ]
    for over, cause, reaction in cases:
        kw = {**OK_T, **over}
        trip = sup().check(check(**kw))
        assert trip is not None, cause
        assert (trip.cause, trip.reaction) == (cause, reaction)
        assert trip.detail


def test_slack_and_stale_sensors_are_ignored_when_not_moving():
    assert sup().check(check(**{**OK_T, "tension_N": [0.1, 5, 5]}, moving=False)) is None
    stale = {**OK_T, "tension_age_s": [1.0, 1.0, 1.0], "tip_age_s": 5.0}
    assert sup().check(check(**stale, moving=False)) is None
    assert sup().check(check(**stale, moving=True)).reaction is Reaction.HALT


def test_trips_latch_escalate_and_reset():
    s = sup()
    first = s.check(check(**{**OK_T, "tension_N": [0.1, 5.0, 5.0]}))
    assert first.reaction is Reaction.HOLD
    assert s.check(check(**{**OK_T, "tension_N": [0.1, 5.0, 5.0]})) is None  # latched
    assert s.later_trips == 1
    worse = s.check(check(**{**OK_T, "tension_N": [50.0, 5.0, 5.0]}))
    assert worse.reaction is Reaction.QUICK_STOP
    assert s.trip is worse and len(s.history) == 2
    s.reset()
    assert s.trip is None and len(s.history) == 2


def test_external_fault_and_disabled_sensors():
    s = Supervisor(LIM)  # no load cells, no tracker on this rig
    assert s.check(check(tension_N=[], tip_age_s=math.inf)) is None
    trip = s.external("emcy:node2:0x8611", Reaction.QUICK_STOP, "following error", 2.0)
    assert trip.reaction is Reaction.QUICK_STOP and s.trip is trip


def test_check_cycle_is_check_of_the_record():
    # The loop's check_cycle (no record made without extra checks) against check(CycleCheck):
    # the same trips, latching, escalation and history over a sequence of cycles.
    import random

    rng = random.Random(7)
    vals = [0.0, 5.0, 9.99, 10.5, -11.0, math.nan, math.inf]
    seen = []

    def extra(c):
        seen.append(c)
        return None

    for with_extra in (False, True):
        a, b = sup(), sup()
        if with_extra:
            a.add_check(extra)
            b.add_check(extra)
        for cycle in range(400):
            kw = dict(
                t_s=cycle * 0.001,
                dt_s=rng.choice([0.001, 0.0, 0.004]),
                q_cmd_mm=[rng.choice(vals) for _ in range(3)],
                q_prev_mm=[rng.choice(vals) for _ in range(3)],
                tension_N=[rng.choice([5.0, 0.1, 45.0, math.nan]) for _ in range(3)],
                tension_age_s=[rng.choice([0.01, 0.5, math.inf]) for _ in range(3)],
                tip_error_mm=rng.choice([1.0, 20.0, math.nan]),
                tip_age_s=rng.choice([0.01, 0.5, math.inf]),
                moving=rng.random() < 0.7,
            )
            if cycle % 50 == 0:
                a.reset()
                b.reset()
            assert a.check(CycleCheck(**kw)) == b.check_cycle(**kw)
            assert a.cycle_worst == b.cycle_worst and a.trip == b.trip
        assert a.history == b.history and a.later_trips == b.later_trips
    assert seen and seen[0] == seen[1]
