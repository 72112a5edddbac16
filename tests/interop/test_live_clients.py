"""The live view with the viewers' own client code: ``@foxglove/ws-protocol``'s
``FoxgloveClient`` (over the ``ws`` package's WebSocket), run with Node from the lock in this
directory (tests/interop/nodejs.py), against :class:`~cdcr_ctl.runlog.live.LiveView` fed by a
stand-in loop thread.

Three clients at once: one offering ``foxglove.sdk.v1`` and ``foxglove.websocket.v1`` (as
Lichtblick does since it learned the SDK's name), one offering ``foxglove.sdk.v1`` only (the
Foxglove app), both receiving tip and tension at the configured rate; and one offering only
``foxglove.websocket.v1`` (``FoxgloveClient.SUPPORTED_SUBPROTOCOL``, the client as shipped, and
viewers from before the SDK), which the foxglove-sdk server refuses in the handshake (HTTP 400).
The daemon's live view during a trajectory: tests/system/test_runlog_views.py.
"""

from __future__ import annotations

import itertools
import logging
import sys
import threading
import time
from pathlib import Path

from cdcr_ctl.runlog import sample_columns, streams
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS
from cdcr_ctl.runlog.live import SDK_SERVER_LOGGER, UPGRADE_HINT, LiveView

sys.path.insert(0, str(Path(__file__).resolve().parent))
import nodejs  # tests/interop/nodejs.py: npm ci from the lock, node scripts

COLS = sample_columns(2, 3, LOOP_EXTRA_COLUMNS)
LOOP_HZ = 500.0
LIVE_HZ = 50.0
WINDOW_S = 2.0
SDK, V1 = "foxglove.sdk.v1", "foxglove.websocket.v1"
#: The foxglove-sdk server's answer to a handshake without its subprotocol.
REFUSAL_BODY = "Missing expected sec-websocket-protocol header"


class _Loop:
    """A stand-in loop: a new row (``t_s``, ``cycle``, every column) ``LOOP_HZ`` times a second."""

    def __init__(self) -> None:
        self.row: dict | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        t0 = time.monotonic()
        for n in itertools.count():
            if self._stop.wait(max(0.0, t0 + n / LOOP_HZ - time.monotonic())):
                return
            row = {c: float(n % 97) for c in COLS}
            row.update(t_s=n / LOOP_HZ, cycle=n, event="")
            self.row = row

    def __enter__(self) -> _Loop:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)


def test_foxglove_ws_protocol_clients_on_the_live_view(caplog):
    caplog.set_level(logging.ERROR, logger=SDK_SERVER_LOGGER)
    topics = [streams.TIP_TRACKED, streams.TENSION]
    with _Loop() as loop, LiveView(lambda: loop.row, COLS, port=0, rate_hz=LIVE_HZ) as live:
        (out,) = nodejs.run_script(
            "live_clients.mjs", live.url, str(WINDOW_S), "0.3", *topics, timeout_s=60
        )
    clients = {c["kind"]: c for c in out["clients"]}
    expected = LIVE_HZ * out["windowSeconds"]
    for kind, protocol in (("both", SDK), ("sdk", SDK)):
        c = clients[kind]
        assert "refused" not in c and not c.get("errors"), c
        assert c["protocol"] == protocol  # the server chose the SDK's name
        assert c["advertised"][streams.TENSION]["schemaName"] == "cdcr.Tension"
        assert set(c["advertised"]) == set(streams.SCHEMAS) - {streams.CAN} | {streams.SCENE}
        for topic in topics:
            got = c["received"][topic]
            # The publisher never exceeds its rate (+2: a tick on each edge of the window); a
            # loaded machine may make it skip ticks, never add them.
            assert 0.5 * expected <= len(got) <= expected + 2, (kind, topic, len(got))
            cycles = [cyc for _, cyc in got]
            assert all(b > a for a, b in itertools.pairwise(cycles))
            # Each message is the loop's latest row: cycles advance by about LOOP_HZ / LIVE_HZ.
            steps = [b - a for a, b in itertools.pairwise(cycles)]
            assert sorted(steps)[len(steps) // 2] >= 0.5 * LOOP_HZ / LIVE_HZ, steps
    v1 = clients["v1"]
    assert v1["offered"] == [V1] and v1["protocol"] is None and not v1["received"]
    assert v1["refused"] == {
        "status": 400,
        "body": "Missing expected sec-websocket-protocol header",
    }
    # The daemon's log says why and what to upgrade.
    (refusal,) = [r.getMessage() for r in caplog.records if "handshake failed" in r.getMessage()]
    assert UPGRADE_HINT in refusal and "Lichtblick 1.22.0" in refusal
