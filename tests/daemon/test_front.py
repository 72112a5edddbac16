"""The front process's pieces (issue #21): status coalescing, the pipe's error round trip, the
shared-memory stop flag seen from another process."""

from __future__ import annotations

import multiprocessing
import threading
import time

import pytest

from cdcr_ctl.control.stopflag import StopFlag
from cdcr_ctl.control.supervisor import Reaction
from cdcr_ctl.daemon.coalesce import Coalescer
from cdcr_ctl.daemon.protocol import ProtocolError
from cdcr_ctl.daemon.rigproc import SHARED_SLOTS, encode_outcome, outcome
from cdcr_ctl.errors import ConfigError, RigError

#: Generous bound for threads to reach a state on a loaded machine (not a timing margin: the
#: test fails only if the state is never reached).
REACH_S = 30.0


def _until(pred, timeout_s: float = REACH_S) -> None:
    end = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < end, "state never reached"
        time.sleep(0.005)


def test_a_status_flood_costs_two_round_trips_and_no_answer_predates_its_request():
    release = threading.Event()
    started: list[int] = []

    def fetch() -> int:
        n = len(started)
        started.append(n)
        if n == 0:
            release.wait()  # the first round trip is in flight while the flood arrives
        return n

    c = Coalescer(fetch)
    answers: dict[int, int] = {}
    first = threading.Thread(target=lambda: answers.__setitem__(-1, c.get()))
    first.start()
    _until(lambda: len(started) == 1)
    flood = [
        threading.Thread(target=lambda i=i: answers.__setitem__(i, c.get())) for i in range(199)
    ]
    for th in flood:
        th.start()
    _until(lambda: c.waiting == 200)
    release.set()
    for th in [first, *flood]:
        th.join(REACH_S)
    assert answers[-1] == 0
    # Every request of the flood arrived while round trip 0 ran: they share round trip 1 (never
    # round trip 0's answer, fetched before they asked).
    assert {answers[i] for i in range(199)} == {1}
    assert c.fetches == 2 and c.calls == 200 and c.waiting == 0


def test_a_failed_round_trip_fails_each_caller_that_shared_it_and_the_next_one_runs():
    calls = []

    def fetch() -> int:
        calls.append(1)
        if len(calls) == 1:
            raise RigError("rig process exited -9")
        return 7

    c = Coalescer(fetch)
    with pytest.raises(RigError, match="exited -9"):
        c.get()
    assert c.get() == 7


def test_errors_cross_the_pipe_with_their_kind_field_and_text():
    def boom(exc):
        raise exc

    with pytest.raises(ProtocolError) as pe:
        outcome(encode_outcome(boom, ProtocolError("outside [0, 1.75] rad", field="args.theta")))
    assert pe.value.field == "args.theta" and str(pe.value) == "args.theta: outside [0, 1.75] rad"
    with pytest.raises(ConfigError) as ce:
        outcome(encode_outcome(boom, ConfigError("rig.yaml", "limits.x", "too big")))
    assert (ce.value.file, ce.value.key) == ("rig.yaml", "limits.x")
    with pytest.raises(RigError, match="drives are disabled"):
        outcome(encode_outcome(boom, RigError("drives are disabled")))
    # A handler bug keeps its type, as the one-process daemon's "internal error: ValueError".
    with pytest.raises(ValueError, match="Maximum allowed size"):
        outcome(encode_outcome(boom, ValueError("Maximum allowed size exceeded")))
    assert outcome(encode_outcome(lambda: {"ok": 1})) == {"ok": 1}


def _loop_in_child(store, n_cycles: int) -> None:
    """A stand-in loop in another process: tick, act on the flag, as ControlLoop does."""
    flag = StopFlag(store)
    seen = 0
    for cycle in range(n_cycles):
        flag.tick(cycle)
        seq = flag.requested
        if seq != seen:
            seen = seq
            flag.acted(seq, cycle)
            return
        time.sleep(0.001)


def test_the_shared_memory_flag_is_raised_in_one_process_and_acted_on_in_another():
    ctx = multiprocessing.get_context("spawn")
    store = ctx.RawArray("q", SHARED_SLOTS)
    store[StopFlag.ACTED_CYCLE] = -1
    flag = StopFlag(store)
    proc = ctx.Process(target=_loop_in_child, args=(store, 10**7))
    proc.start()
    try:
        _until(lambda: flag.cycle > 0, 60.0)
        cycle0 = flag.cycle
        seq = flag.request(Reaction.QUICK_STOP)
        _until(lambda: flag.acted_cycle(seq) is not None, 60.0)
        assert flag.acted_cycle(seq) >= cycle0
        assert Reaction(store[StopFlag.REACTION]) is Reaction.QUICK_STOP
    finally:
        proc.join(30)
        if proc.is_alive():
            proc.kill()
    assert proc.exitcode == 0


def test_shutdown_trusts_the_rig_process_sentinel_not_a_lost_reap(caplog):
    """The pipe thread may reap the ended rig process while shutdown waits for it; the front's
    own waitpid then fails and ``is_alive()`` still says True. Shutdown must go by the process's
    sentinel (readable once it ended, whoever reaped it): no "did not end in 12 s" error, no
    12 s wait."""
    import logging
    import multiprocessing
    import time
    from types import SimpleNamespace

    from cdcr_ctl.daemon.front import FrontDaemon
    from cdcr_ctl.daemon.notify import SystemdNotifier

    child = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(0.0,))
    child.start()
    child.join(30)

    class LostReap:  # what the front's Process looks like after the other thread reaped it
        sentinel = child.sentinel
        exitcode = None

        def is_alive(self) -> bool:
            return True

        def join(self, timeout=None) -> None:
            pass

        def terminate(self) -> None:
            raise AssertionError("an ended rig process was terminated")

        kill = terminate

    front = FrontDaemon.__new__(FrontDaemon)
    front.notifier = SystemdNotifier("")
    front.proc = LostReap()
    front.stop_proc = SimpleNamespace(pid=None)  # the stop line's process, never started here
    front.flag = SimpleNamespace(request=lambda reaction: 0)
    front._call = lambda *a, **k: (_ for _ in ()).throw(RuntimeError("rig gone"))
    front.server = None
    front.intake = SimpleNamespace(close=lambda: None)
    front._conn = SimpleNamespace(close=lambda: None)
    t0 = time.monotonic()
    with caplog.at_level(logging.INFO, logger="cdcr_ctl.daemon.front"):
        front.shutdown("test")
    assert time.monotonic() - t0 < 2.0
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text
    assert front.state == "stopped"
