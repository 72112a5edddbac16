"""Helpers: simulated EPOS nodes and a DriveGroup on one python-can virtual channel per test, a spy
bus that sees every frame, a cycle thread like the control loop's, and polling waits."""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import can
from hypothesis import strategies as st

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.sim.epos.rig import SimDriveBus

ROOT = Path(__file__).resolve().parents[2]
_channels = itertools.count()
#: Generous waits: the tests assert what happens, not how fast (timing is in benchmarks/).
WAIT_S = 5.0


def channel() -> str:
    return f"drives-test-{next(_channels)}"


def drive_cfgs(n: int = 3, kind: str = "epos4", mode: str = "csp", **kw) -> list[DriveConfig]:
    return [
        DriveConfig(
            name=f"m{i}", cable=f"c{i}", node_id=i, type=kind, mode=mode, counts_per_mm=1238.6, **kw
        )
        for i in range(1, n + 1)
    ]


def bus_cfg(ch: str, **kw) -> CanBusConfig:
    base = {
        "interface": "virtual",
        "channel": ch,
        "sync_period_s": 0.002,
        "feedback_timeout_s": 0.2,
    }
    base.update(kw)
    return CanBusConfig(**base)


@dataclass
class Rig:
    """Simulated drives, the group under test, a spy that records every frame on the channel."""

    sim: SimDriveBus
    group: DriveGroup
    spy: can.BusABC
    cfg: CanBusConfig
    drives: list[DriveConfig]

    def close(self) -> None:
        self.group.close()
        self.spy.shutdown()
        self.sim.stop()


def make_rig(drives: Sequence[DriveConfig] | None = None, start: bool = True, **bus_kw) -> Rig:
    """Simulated nodes + group (booted and configured when ``start``) on a fresh channel."""
    drives = list(drives or drive_cfgs())
    ch = channel()
    cfg = bus_cfg(ch, **bus_kw)
    sim = SimDriveBus(drives, "virtual", ch, sync_period_s=cfg.sync_period_s).start()
    spy = can.Bus(interface="virtual", channel=ch)
    group = DriveGroup(can.Bus(interface="virtual", channel=ch), cfg, drives)
    rig = Rig(sim, group, spy, cfg, drives)
    if start:
        try:
            group.boot()
            group.configure()
        except BaseException:
            rig.close()
            raise
    return rig


class Cycler:
    """Sends cycles (targets + SYNC) from a thread at ``period_s``, like the control loop."""

    def __init__(
        self,
        group: DriveGroup,
        period_s: float | None = None,
        targets: Callable[[int], list[int]] | None = None,
    ) -> None:
        self.group = group
        self.period_s = period_s or group.period_s
        self.targets = [0] * len(group.feedback())
        self._fn = targets
        self.cycles = 0
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        t0 = time.monotonic()
        while not self._stop.is_set():
            tg = self._fn(self.cycles) if self._fn else list(self.targets)
            self.group.send_cycle(tg)
            self.cycles += 1
            delay = t0 + self.cycles * self.period_s - time.monotonic()
            if delay > 0:
                time.sleep(delay)

    def __enter__(self) -> Cycler:
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join(2)


def is_heartbeat(m: can.Message) -> bool:
    return 0x701 <= m.arbitration_id <= 0x77F


def drain(spy: can.BusABC, quiet_s: float = 0.05, max_s: float = 1.0) -> list[can.Message]:
    """Frames the spy saw until no frame but heartbeats came for ``quiet_s`` (at most ``max_s``)."""
    out = []
    now = time.monotonic()
    end, quiet_end = now + max_s, now + quiet_s
    while (now := time.monotonic()) < min(end, quiet_end):
        m = spy.recv(min(end, quiet_end) - now)
        if m is None:
            break
        out.append(m)
        if not is_heartbeat(m):
            quiet_end = time.monotonic() + quiet_s
    return out


def collect(spy: can.BusABC, duration_s: float) -> list[can.Message]:
    """Every frame the spy sees during ``duration_s``."""
    out = []
    end = time.monotonic() + duration_s
    while (left := end - time.monotonic()) > 0:
        m = spy.recv(left)
        if m is not None:
            out.append(m)
    return out


def wait_until(pred: Callable[[], bool], timeout_s: float = WAIT_S) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return pred()


def frames_of(msgs: Sequence[can.Message], cob_id: int) -> list[bytes]:
    return [bytes(m.data) for m in msgs if m.arbitration_id == cob_id]


def can_messages() -> st.SearchStrategy[can.Message]:
    """Hypothesis strategy: any classic CAN frame (standard or extended id, data or remote)."""
    return st.builds(
        lambda ext, remote, data, ident: can.Message(
            arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF),
            is_extended_id=ext,
            is_remote_frame=remote,
            dlc=len(data),
            data=b"" if remote else data,
        ),
        st.booleans(),
        st.booleans(),
        st.binary(max_size=8),
        st.integers(0, 0x1FFFFFFF),
    )


def assert_same_frame(back: can.Message | None, msg: can.Message) -> None:
    """``back`` (a frame parsed back from its slcan line) is ``msg``: id, kind, DLC and data."""
    assert back is not None
    assert (back.arbitration_id, back.is_extended_id, back.is_remote_frame, back.dlc) == (
        msg.arbitration_id,
        msg.is_extended_id,
        msg.is_remote_frame,
        msg.dlc,
    )
    assert bytes(back.data) == (b"" if msg.is_remote_frame else bytes(msg.data))
