"""The CAN traffic log's own writer thread (issue #21): the send and receive paths only queue;
every frame reaches the file in order, and a write error stops the log without reaching them."""

from __future__ import annotations

import threading
import time

import can

from cdcr_ctl.drives.group.traffic import (
    BACKLOG_FRAMES,
    DRAIN_PERIOD_S,
    TAP_BATCH_FRAMES,
    DeferredTrafficLog,
)


class _Collect(can.Listener):
    def __init__(self, fail_at: int | None = None) -> None:
        self.frames: list[tuple[int, bytes]] = []
        self.stopped = 0
        self.fail_at = fail_at

    def on_message_received(self, msg: can.Message) -> None:
        if self.fail_at is not None and len(self.frames) == self.fail_at:
            raise OSError(28, "No space left on device")
        self.frames.append((msg.arbitration_id, bytes(msg.data)))

    def stop(self) -> None:
        self.stopped += 1


def _msg(cob: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob, data=data, is_extended_id=False)


def test_every_queued_frame_reaches_the_listener_in_order_and_stop_flushes_them():
    sink = _Collect()
    log = DeferredTrafficLog(sink, on_failure=lambda text: None)
    sent = [(0x080, b""), (0x201, b"\x0f\x00"), (0x181, b"\x37\x06\x00\x00"), (0x701, b"\x05")]
    for _ in range(250):
        for cob, data in sent:
            log.on_message_received(_msg(cob, data))
    log.stop()
    assert sink.frames == sent * 250
    assert sink.stopped == 1 and not log.failed


def test_a_write_error_stops_the_log_and_is_reported_once():
    sink = _Collect(fail_at=3)
    failures: list[str] = []
    log = DeferredTrafficLog(sink, on_failure=failures.append)
    for i in range(10):
        log.on_message_received(_msg(0x080 + i, b""))
    log.drain()
    assert log.failed and len(sink.frames) == 3
    assert failures == ["CAN traffic log: [Errno 28] No space left on device"]
    log.on_message_received(_msg(0x080, b""))  # after the failure: dropped, no error raised
    log.stop()
    assert len(sink.frames) == 3 and sink.stopped == 1 and len(failures) == 1


def test_the_writer_waits_for_quiet_and_writes_when_it_holds():
    # ``quiet`` false: the writer thread keeps the frames queued (it polls, writes nothing);
    # once true, they arrive in order without stop(). Waits are bounded by events, not timed
    # margins: "nothing written" is checked after the thread provably ran its drain (it asked
    # quiet() at least twice).
    sink = _Collect()
    asked = threading.Event()
    calls = [0]
    is_quiet = [False]

    def quiet() -> bool:
        calls[0] += 1
        if calls[0] >= 2:
            asked.set()
        return is_quiet[0]

    log = DeferredTrafficLog(sink, on_failure=lambda text: None, quiet=quiet)
    for i in range(20):
        log.on_message_received(_msg(0x180 + i, b"\x01"))
    assert asked.wait(10.0)
    assert sink.frames == []
    is_quiet[0] = True
    end = time.monotonic() + 10.0
    while len(sink.frames) < 20 and time.monotonic() < end:
        time.sleep(DRAIN_PERIOD_S)
    assert sink.frames == [(0x180 + i, b"\x01") for i in range(20)]
    log.stop()
    assert sink.stopped == 1


def test_a_backlog_is_written_even_when_never_quiet_and_stop_writes_the_rest():
    sink = _Collect()
    log = DeferredTrafficLog(sink, on_failure=lambda text: None, quiet=lambda: False)
    n = BACKLOG_FRAMES + 100
    for i in range(n):
        log.on_message_received(_msg(0x200 + i % 16, b""))
    end = time.monotonic() + 10.0
    while len(sink.frames) < 101 and time.monotonic() < end:
        time.sleep(DRAIN_PERIOD_S)
    # The thread wrote down to the backlog limit (not below: never quiet).
    assert len(sink.frames) == 101
    log.stop()  # writes everything left, quiet or not
    assert len(sink.frames) == n and sink.stopped == 1


class _BatchTap(can.Listener):
    def __init__(self) -> None:
        self.batches: list[list[tuple[int, bytes]]] = []
        self.stopped = 0

    def on_messages(self, msgs: list[can.Message]) -> None:
        self.batches.append([(m.arbitration_id, bytes(m.data)) for m in msgs])

    def on_message_received(self, msg: can.Message) -> None:  # never used: batches only
        raise AssertionError("the tap takes batches")

    def stop(self) -> None:
        self.stopped += 1


def test_a_tap_gets_every_frame_in_order_a_batch_at_a_time_and_stops_with_the_log():
    sink, tap = _Collect(), _BatchTap()
    log = DeferredTrafficLog(sink, on_failure=lambda text: None, tap=tap)
    sent = [(0x200 + i % 16, bytes([i % 256])) for i in range(3 * TAP_BATCH_FRAMES + 5)]
    for cob, data in sent:
        log.on_message_received(_msg(cob, data))
    log.stop()
    assert sink.frames == sent
    assert [f for b in tap.batches for f in b] == sent
    assert all(0 < len(b) <= TAP_BATCH_FRAMES for b in tap.batches)
    assert len(tap.batches) < len(sent)  # batches, not a call per frame
    assert sink.stopped == 1 and tap.stopped == 1


def test_a_tap_without_batches_gets_the_frames_one_by_one():
    sink, tap = _Collect(), _Collect()
    log = DeferredTrafficLog(sink, on_failure=lambda text: None, tap=tap)
    sent = [(0x180 + i % 3, bytes([i % 256])) for i in range(150)]
    for cob, data in sent:
        log.on_message_received(_msg(cob, data))
    log.stop()
    assert sink.frames == sent and tap.frames == sent
    assert sink.stopped == 1 and tap.stopped == 1


def test_a_write_error_with_a_tap_stops_both_and_is_reported_once():
    sink, tap = _Collect(fail_at=3), _BatchTap()
    failures: list[str] = []
    log = DeferredTrafficLog(sink, on_failure=failures.append, tap=tap)
    for i in range(10):
        log.on_message_received(_msg(0x080 + i, b""))
    log.drain()
    assert log.failed and len(sink.frames) == 3 and tap.stopped == 1
    assert failures == ["CAN traffic log: [Errno 28] No space left on device"]
    log.stop()
    assert sink.stopped == 1 and tap.stopped == 1 and len(failures) == 1
