"""The shared latest-value holder: ages, stale flag, invalidation, one writer and many readers."""

from __future__ import annotations

import math
import threading

import pytest

from cdcr_ctl.sensors.sample import Latest, LatestValue, Stamped


class ManualClock:
    def __init__(self, t_s: float = 100.0) -> None:
        self.t_s = t_s

    def __call__(self) -> float:
        return self.t_s


def test_no_value_yet_is_nan_inf_and_stale():
    holder: LatestValue[float] = LatestValue(0.1, ManualClock())
    assert holder.stamped is None
    got = holder.latest()
    assert got.value is None and math.isnan(got.t_s) and got.age_s == math.inf
    assert got.stale and got.seq == 0


def test_age_and_stale_follow_the_clock():
    clock = ManualClock(100.0)
    holder: LatestValue[str] = LatestValue(0.1, clock)
    stamped = holder.publish("a")
    assert stamped == Stamped("a", 100.0, 1)
    clock.t_s = 100.1
    assert holder.latest() == Latest("a", 100.0, pytest.approx(0.1), False, 1)  # at the limit
    clock.t_s = 100.25
    assert holder.latest().stale
    assert holder.latest(now_s=100.05).age_s == pytest.approx(0.05)
    holder.publish("b", t_s=100.2)  # acquisition time given by the sensor
    got = holder.latest()
    assert (got.value, got.age_s, got.stale, got.seq) == ("b", pytest.approx(0.05), False, 2)


def test_invalidate_flags_stale_until_the_next_publish():
    clock = ManualClock()
    holder: LatestValue[int] = LatestValue(1.0, clock)
    holder.publish(1)
    holder.invalidate()
    got = holder.latest()
    assert got.value == 1 and got.age_s == 0.0 and got.stale
    holder.publish(2)
    assert not holder.latest().stale


def test_stale_after_must_be_positive():
    with pytest.raises(ValueError):
        LatestValue(0.0)


def test_one_writer_many_readers_see_monotonic_consistent_values():
    holder: LatestValue[tuple[int, int]] = LatestValue(10.0)
    n = 20000
    stop = threading.Event()
    problems: list[str] = []

    def reader() -> None:
        last = 0
        while not stop.is_set():
            got = holder.latest()
            if got.value is None:
                continue
            a, b = got.value
            if a != b or got.seq != a or got.seq < last:
                problems.append(f"{got}")
            last = got.seq

    readers = [threading.Thread(target=reader) for _ in range(3)]
    for t in readers:
        t.start()
    for k in range(1, n + 1):
        holder.publish((k, k))
    stop.set()
    for t in readers:
        t.join()
    assert problems == []
    assert holder.latest().seq == n
