"""A rig's drives against simulated EPOS nodes on a python-can virtual bus (one process)."""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path

import can

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.drives.group import DriveGroup
from cdcr_ctl.sim.epos.rig import SimDriveBus

ROOT = Path(__file__).resolve().parents[2]
_channels = itertools.count()


def rig_config(**can_updates):
    cfg = load_rig_config(ROOT / "config" / "qi2023.yaml")
    can_cfg = cfg.can.model_copy(
        update={"interface": "virtual", "channel": f"drv-{next(_channels)}", **can_updates}
    )
    return cfg.model_copy(update={"can": can_cfg})


class Cycler:
    """Sends cycles (targets + SYNC) from a thread, like the control loop does."""

    def __init__(self, group: DriveGroup, period_s: float) -> None:
        self.group, self.period_s = group, period_s
        self.targets = [0] * len(group.feedback())
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.group.send_cycle(list(self.targets))
            time.sleep(self.period_s)

    def __enter__(self) -> Cycler:
        self._t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._t.join(2)


def make_rig():
    """(config, simulated drives, drive group booted and configured, frame recorder)."""
    cfg = rig_config(sync_period_s=0.002)
    sim = SimDriveBus(cfg, "virtual", cfg.can.channel).start()
    spy = can.Bus(interface="virtual", channel=cfg.can.channel)
    bus = can.Bus(interface="virtual", channel=cfg.can.channel, receive_own_messages=False)
    by = {d.cable: d for d in cfg.drives}
    group = DriveGroup(bus, cfg.can, [by[c.name] for c in cfg.robot.cables])
    group.boot()
    group.configure()
    return cfg, sim, group, spy


def close_rig(cfg, sim, group, spy) -> None:
    group.close()
    spy.shutdown()
    sim.stop()


def drain(spy: can.BusABC, timeout_s: float = 0.05, max_s: float = 0.3) -> list[can.Message]:
    """Frames the spy saw until it is quiet for ``timeout_s`` or ``max_s`` has passed."""
    out = []
    end = time.monotonic() + max_s
    while time.monotonic() < end:
        m = spy.recv(timeout_s)
        if m is None:
            break
        out.append(m)
    return out


def wait_until(pred, timeout_s: float = 5.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return False
