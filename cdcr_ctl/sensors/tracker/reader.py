"""The tip samples and the part shared by both tracker readers (transform, latest value, lost).

:class:`TipTracker` is the base of :class:`~cdcr_ctl.sensors.tracker.NatNetTracker` and
:class:`~cdcr_ctl.sensors.tracker.LineStreamTracker`: it turns a body pose into the tip in the
robot base frame (:mod:`cdcr_ctl.sensors.tracker.frames`), publishes it with its acquisition
time, counts what came in and flags the tracker lost after a silence.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.loadcell import TrafficLog
from cdcr_ctl.sensors.polling import PollingReader
from cdcr_ctl.sensors.sample import Clock, LatestValue
from cdcr_ctl.sensors.tracker.frames import TrackerTransform

#: Longest wait of one poll on the socket (s); bounds how long ``stop()`` takes.
RECV_POLL_S = 0.02
#: Receive buffer per datagram (bytes): a NatNet datagram is at most 65535 + 4.
RECV_BUFFER_BYTES = 65536 + 4
#: Most datagrams taken in by one poll (a flood must not keep ``stop()`` waiting).
MAX_DATAGRAMS_PER_POLL = 256


#: A frame number this much or less below the newest is a reordered/duplicate datagram;
#: further below is a server restart and is accepted.
REORDER_WINDOW_FRAMES = 1000
#: The same for line-stream timestamps (s).
REORDER_WINDOW_S = 1.0


# -- samples --------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TipMeasurement:
    """What a tracker reader publishes: the tip in the base frame and where it came from.

    ``position_mm``: tip, base frame (mm). ``rotation``: R_base_tip, or None when the source
    has no orientation. ``frame``: the tracker's frame number (line streams: lines so far).
    ``tracker_time_s``: the sender's timestamp (s, its own clock). ``latency_s``: what the
    sender reported as its own delay from exposure to transmission (0 when unknown).
    """

    position_mm: np.ndarray
    rotation: np.ndarray | None
    frame: int
    tracker_time_s: float
    latency_s: float


@dataclass(frozen=True, slots=True)
class TipSample:
    """The loop's view of the tip: newest measurement, its time and age, and its health.

    ``position_mm``: tip in the robot base frame (mm), NaN before the first sample;
    ``rotation``: R_base_tip or None. ``t_s``: acquisition time on the reader's clock
    (time.monotonic: receipt minus the sender's reported latency). ``age_s``: now - t_s (inf
    before the first sample). ``stale``: older than ``stale_after_s``, none yet, or the tracker is
    lost. ``occluded``: the newest frame had no valid pose of the body (it is not published, so
    the previous pose ages). ``frame``, ``tracker_time_s``: from the tracker. ``seq``: count of
    published samples (tells a reader whether this one is new).
    """

    position_mm: np.ndarray
    rotation: np.ndarray | None
    t_s: float
    age_s: float
    stale: bool
    occluded: bool
    frame: int
    tracker_time_s: float
    seq: int


@dataclass
class TrackerStats:
    """Counters of one tracker link since the reader was made.

    ``received``: datagrams (TCP: reads) taken in; ``samples``: tip samples published; ``bad``:
    undecodable datagrams or lines; ``occluded``: frames without a valid pose of the body;
    ``out_of_order``: reordered or repeated frames dropped; ``foreign``: datagrams from another
    host; ``other_messages``: NatNet messages other than frames and server info;
    ``discarded_bytes``: bytes thrown away with bad data.
    """

    received: int = 0
    samples: int = 0
    bad: int = 0
    occluded: int = 0
    out_of_order: int = 0
    foreign: int = 0
    other_messages: int = 0
    discarded_bytes: int = 0


_NAN3 = np.full(3, np.nan)
_NAN3.setflags(write=False)


class TipTracker(PollingReader):
    """Shared part of the tracker readers: transform, latest value, stats, lost detection.

    ``transform``: tracker -> base. ``stale_after_s`` (s): age beyond which a sample is stale.
    ``lost_after_s`` (s): silence after which :attr:`failure` says the tracker is lost (cleared
    by the next measurement; the thread keeps running). ``clock``: seconds, default
    time.monotonic (tests inject one).
    """

    def __init__(
        self,
        transform: TrackerTransform,
        *,
        port_name: str,
        stale_after_s: float = 0.1,
        lost_after_s: float = 1.0,
        clock: Clock = time.monotonic,
    ) -> None:
        super().__init__()
        self.transform = transform
        self.port_name = port_name
        self.clock = clock
        self.lost_after_s = float(lost_after_s)
        self.stats = TrackerStats()
        self.traffic = TrafficLog()
        self.values: LatestValue[TipMeasurement] = LatestValue(stale_after_s, clock)
        self.occluded = False
        self._last_rx_s: float | None = None  # last time the source showed life
        self._lost = False
        #: Why the last bad datagram or line was rejected (for logs).
        self.last_error = ""

    # -- what the loop calls ------------------------------------------------------------------

    def latest(self, now_s: float | None = None) -> TipSample:
        """Newest tip sample aged at ``now_s`` (s; default: the clock now). Never blocks."""
        got = self.values.latest(now_s)
        m = got.value
        if m is None:
            return TipSample(_NAN3, None, math.nan, math.inf, True, self.occluded, 0, math.nan, 0)
        stale = got.stale or self._lost or (self.failure is not None)
        return TipSample(
            m.position_mm,
            m.rotation,
            got.t_s,
            got.age_s,
            stale,
            self.occluded,
            m.frame,
            m.tracker_time_s,
            got.seq,
        )

    def position_and_age(self, now_s: float | None = None) -> tuple[np.ndarray, float]:
        """(tip in the base frame (mm), age (s)): NaNs and inf before the first sample."""
        s = self.latest(now_s)
        return s.position_mm.copy(), s.age_s

    # -- for subclasses ---------------------------------------------------------------------

    def _alive(self, t_rx: float) -> None:
        """The source showed life at ``t_rx``: clear a 'lost' failure."""
        self._last_rx_s = t_rx
        if self._lost:
            self._lost = False
            self.failure = None

    def _publish(
        self,
        position_units: np.ndarray | tuple[float, ...],
        R_tracker_body: np.ndarray,
        *,
        has_rotation: bool,
        frame: int,
        tracker_time_s: float,
        latency_s: float,
        t_rx: float,
    ) -> None:
        p, R = self.transform.tip_in_base(position_units, R_tracker_body)
        p.setflags(write=False)
        R.setflags(write=False)
        m = TipMeasurement(p, R if has_rotation else None, frame, tracker_time_s, latency_s)
        self.values.publish(m, t_rx - latency_s)
        self.occluded = False
        self.stats.samples += 1

    def _check_lost(self, now: float) -> bool:
        """Flag the tracker lost after ``lost_after_s`` of silence; True while lost."""
        last = self._last_rx_s
        if last is None or now - last <= self.lost_after_s:
            return self._lost
        if not self._lost:
            self._lost = True
            self.values.invalidate()
            self.failure = SensorError(
                self.port_name,
                f"tracker lost: nothing received for {now - last:.2f} s "
                f"(limit {self.lost_after_s} s); stopped streaming or unreachable",
            )
        return True

    def _bad(self, data: bytes, why: str) -> None:
        self.stats.bad += 1
        self.stats.discarded_bytes += len(data)
        self.traffic.add("rx", data[:64])
        self.last_error = why
