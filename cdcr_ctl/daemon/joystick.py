"""Live joystick end-following sessions of the daemon (``joystick`` command).

A session is one run of the control loop whose setpoint source is the vertebra arm's
:class:`~cdcr_ctl.model.vertebra.follow.EndFollowSource` fed by the rig's joystick
(``sensors.joystick``): a local evdev device or a network joystick
(:func:`cdcr_ctl.sensors.joystick.open_joystick`). Everything design-specific comes from the
config (:func:`~cdcr_ctl.config.designs.vertebra_arm`, ``follow_params``) and the model; a rig
whose config has no vertebra section is refused by that same config check.

Life cycle: the joystick is opened when the session starts (``start``) and closed when its run
ends, whatever ended it: ``stop``, the ``seconds`` limit, a supervisor trip, a new run replacing
it, daemon shutdown. The session's watcher thread (started by :meth:`JoystickSession.attach`)
notices the end (it polls the run's state, off the loop's path) and closes the reader.

Losing the joystick mid-session is treated like a stale sensor: the session's check in the
supervisor (one of its ``extra_checks``) trips ``joystick_lost`` with reaction HALT, so the loop
holds the last command (drives stay enabled), ends the run as ``tripped`` with the cause in its
log (``event`` column and the run's end reason) and latches the trip until ``reset-fault``. The
source itself stops steering as soon as the stick reads disconnected (it holds the pose it last
gave), so no cycle between the loss and the trip moves the arm on a stale stick.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.control.supervisor import CycleCheck, Reaction, Supervisor, Trip
from cdcr_ctl.errors import ConfigError, RigError

log = logging.getLogger(__name__)

#: Supervisor cause of a joystick that failed mid-session.
JOYSTICK_LOST = "joystick_lost"
#: How often the watcher looks whether the session's run has ended (s).
SESSION_WATCH_S = 0.05


class SessionSource:
    """SetpointSource of a live session: an end-following source, a time limit, a stick.

    ``duration_s``: the ``seconds`` limit (inf: until ``stop``). Once the time is up or the
    stick reads disconnected, the source holds the pose it gave last and never reads the stick
    again (the loop keeps sampling a completed run's source).
    """

    def __init__(self, follow: Any, stick: Any, duration_s: float = math.inf) -> None:
        self.follow = follow
        self.stick = stick
        self._duration_s = float(duration_s)
        self._last: np.ndarray = np.array(follow.planner.psi, dtype=float)
        self.frozen_reason = ""

    @property
    def duration_s(self) -> float:
        return self._duration_s

    @property
    def frozen(self) -> bool:
        return bool(self.frozen_reason)

    def sample(self, t_s: float) -> np.ndarray:
        if not self.frozen:
            if self.stick.failure is not None:
                self.frozen_reason = f"joystick lost: {self.stick.failure}"
            elif t_s >= self._duration_s:
                self.frozen_reason = "time limit"
            else:
                self._last = np.asarray(self.follow.sample(t_s), dtype=float)
        return self._last

    def read_stick(self) -> tuple[float, float, frozenset[str]]:
        """The joystick as :class:`EndFollowSource` reads it; neutral once disconnected."""
        st = self.stick.latest()
        if not st.connected:
            return 0.0, 0.0, frozenset()
        return st.x, st.y, st.buttons


def check_session_config(cfg: RigConfig, config_path: str | Path) -> JoystickConfig:
    """The joystick section, or :class:`ConfigError` naming the key that rules a session out.

    The design check is the model's own (:func:`~cdcr_ctl.config.designs.vertebra_arm`).
    """
    from cdcr_ctl.config.designs import vertebra_arm

    js = cfg.sensors.joystick
    if js is None:
        raise ConfigError(
            str(config_path),
            "sensors.joystick",
            "the rig has no joystick: add a sensors.joystick section"
            " (device: an evdev path, or tcp://HOST:PORT for a network joystick)",
        )
    try:
        vertebra_arm(cfg, str(config_path))
    except ConfigError as exc:
        raise ConfigError(
            str(config_path),
            exc.key,
            f"joystick end-following needs the vertebra model: {exc.detail}",
            exc.value,
        ) from exc
    return js


def end_follow_source(cfg: RigConfig, psi0: np.ndarray, read: Any, source: str = "") -> Any:
    """An :class:`EndFollowSource` over the rig's planner, starting at ``psi0`` (N, 2; rad)."""
    from cdcr_ctl.config.designs import follow_params, vertebra_arm
    from cdcr_ctl.errors import ModelError
    from cdcr_ctl.model.vertebra import EndFollowPlanner
    from cdcr_ctl.model.vertebra.follow import EndFollowSource

    assert cfg.vertebra is not None and cfg.sensors.joystick is not None
    arm = vertebra_arm(cfg, source or "rig config")
    try:
        planner = EndFollowPlanner(arm, follow_params(cfg), psi=np.array(psi0, dtype=float))
    except ModelError as exc:
        raise RigError(
            f"cannot start end-following from the commanded pose {np.round(psi0, 4).tolist()}"
            f" rad: {exc} (vertebra.follow.theta_max_rad = {cfg.vertebra.follow.theta_max_rad})"
        ) from exc
    return EndFollowSource(
        planner,
        read,
        cfg.sensors.joystick.advance_button,
        speed_fraction=cfg.vertebra.follow.speed_fraction,
    )


class JoystickSession:
    """One live session: its source, its joystick, its run and the watcher that ends it."""

    def __init__(self, source: SessionSource, device: str) -> None:
        self.source = source
        self.stick = source.stick
        self.device = device
        self.run: Any = None
        self.ended = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._supervisor: Supervisor | None = None
        self._closed = False

    @classmethod
    def open(
        cls,
        cfg: RigConfig,
        config_path: str | Path,
        psi0: np.ndarray,
        opener: Callable[[JoystickConfig], Any],
        duration_s: float = math.inf,
    ) -> JoystickSession:
        """Check the config, plan from ``psi0``, then open the joystick (``opener``)."""
        js = check_session_config(cfg, config_path)
        holder: list[SessionSource] = []
        follow = end_follow_source(cfg, psi0, lambda: holder[0].read_stick(), str(config_path))
        stick = opener(js)  # SensorError naming the device when it cannot be opened
        source = SessionSource(follow, stick, duration_s)
        holder.append(source)
        return cls(source, js.device or "evdev (first device with both axes)")

    def check(self, c: CycleCheck) -> Trip | None:
        """The supervisor's per-cycle check: HALT when the joystick failed (like a stale
        sensor)."""
        failure = self.stick.failure
        if failure is None:
            return None
        return Trip(JOYSTICK_LOST, Reaction.HALT, str(failure), c.t_s)

    def attach(self, run: Any, supervisor: Supervisor) -> None:
        """Watch ``run`` (already handed to the loop); end the session when it ends."""
        self.run = run
        self._supervisor = supervisor
        self._thread = threading.Thread(target=self._watch, name="joystick-session", daemon=True)
        self._thread.start()

    @property
    def active(self) -> bool:
        return not self.ended.is_set()

    def _watch(self) -> None:
        while not self._stop.wait(SESSION_WATCH_S):
            if self.run is None or self.run.state != "running":
                break
        self.close()

    def close(self) -> None:
        """Stop checking the joystick and close it (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._supervisor is not None:
            self._supervisor.remove_check(self.check)
        with contextlib.suppress(Exception):
            self.stick.close()
        self.ended.set()
        log.info(
            "joystick session %s ended: %s",
            getattr(self.run, "id", "?"),
            getattr(self.run, "end_reason", "") or "closed",
        )

    def shutdown(self) -> None:
        """Daemon shutdown: end the watcher now and close the joystick."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self.close()

    def status(self) -> dict[str, Any]:
        """For ``status``: device, stick state, planner, steps, how the session ended."""
        st = self.stick.latest()
        follow = self.source.follow
        planner = follow.planner
        run = self.run
        return {
            "active": self.active,
            "device": self.device,
            "run": getattr(run, "id", None),
            "state": getattr(run, "state", None),
            "end_reason": getattr(run, "end_reason", "") or None,
            "connected": st.connected,
            "failure": None if self.stick.failure is None else str(self.stick.failure),
            "x": round(st.x, 3),
            "y": round(st.y, 3),
            "buttons": sorted(st.buttons),
            "reports": st.seq,
            "mode": planner.mode.value,
            "distal_target_rad": [round(float(v), 4) for v in planner.target[-1]],
            "steps": len(follow.log),
            "frozen": self.source.frozen_reason or None,
        }
