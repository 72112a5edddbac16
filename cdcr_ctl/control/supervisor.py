"""Safety supervisor: per-cycle checks of commands and measurements against the rig's limits.

Pure logic, no I/O: the loop feeds it one :class:`CycleCheck` per cycle and applies the returned
:class:`Verdict`. Each limit has one defined reaction, in increasing severity:

- ``HOLD``: the offending command is not sent; the last safe command is held and the running
  trajectory ends (displacement limit, slack cable; a cable the loop is pulling back in after a
  recovery, ``retensioning``, is not slack by fault).
- ``HALT``: the trajectory ends and the drives hold the last command, still enabled (velocity limit,
  stale sensor, tracker-vs-model divergence, log write failure).
- ``QUICK_STOP``: CiA 402 quick stop of every drive, then disabled (overload tension, drive fault,
  heartbeat loss, bus failure).

A trip latches until :meth:`Supervisor.reset`; the first cause is kept (later ones are counted), so
the status and the log name what went wrong first.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from cdcr_ctl.config.control import LimitsConfig


class Reaction(enum.IntEnum):
    """What the loop does about a tripped limit, ordered by severity."""

    NONE = 0
    HOLD = 1
    HALT = 2
    QUICK_STOP = 3


@dataclass(frozen=True)
class Trip:
    """One tripped limit: ``cause`` machine-readable (``tension_high:cable2``), ``detail`` text."""

    cause: str
    reaction: Reaction
    detail: str
    t_s: float


@dataclass(frozen=True)
class CycleCheck:
    """What the supervisor sees in one cycle. Cables indexed 0..K-1; NaN means not measured.

    ``q_cmd_mm``: displacement about to be sent; ``q_prev_mm``: the one sent last cycle;
    ``tension_N``/``tension_age_s``: latest load-cell samples and their ages (s);
    ``tip_error_mm``: distance between tracked tip and model tip (NaN when no tracker);
    ``tip_age_s``: age of the tracker sample (inf when none yet);
    ``retensioning``: per cable, whether the loop is pulling a paid-out cable back in (its offset
    ramping towards the model's command after a recovery): a slack reading there is what the
    ramp is removing, not a ``tension_low`` trip; empty: none.
    """

    t_s: float
    dt_s: float
    q_cmd_mm: Sequence[float]
    q_prev_mm: Sequence[float]
    tension_N: Sequence[float] = ()
    tension_age_s: Sequence[float] = ()
    tip_error_mm: float = math.nan
    tip_age_s: float = math.inf
    moving: bool = True
    retensioning: Sequence[bool] = ()


@dataclass
class Supervisor:
    """Checks every cycle against ``limits``; trips latch until :meth:`reset`.

    ``use_tension``/``use_tracker`` say whether those sensors are part of this rig (a rig without
    load cells does not trip on stale tensions).
    """

    limits: LimitsConfig
    use_tension: bool = False
    use_tracker: bool = False
    trip: Trip | None = None
    later_trips: int = 0
    history: list[Trip] = field(default_factory=list)
    #: The worst limit violated in the last checked cycle, latched or not: the loop never sends a
    #: command that violates a limit, even while an earlier trip is latched.
    cycle_worst: Trip | None = None
    #: More per-cycle checks (a session's own sensors, e.g. a joystick): each returns a Trip for
    #: this cycle or None; their trips latch and escalate like the built-in limits'. Replaced as
    #: a whole (:meth:`add_check`, :meth:`remove_check`) so the loop thread sees a consistent tuple.
    extra_checks: tuple[Callable[[CycleCheck], Trip | None], ...] = ()

    def add_check(self, check: Callable[[CycleCheck], Trip | None]) -> None:
        self.extra_checks = (*self.extra_checks, check)

    def remove_check(self, check: Callable[[CycleCheck], Trip | None]) -> None:
        self.extra_checks = tuple(c for c in self.extra_checks if c != check)  # bound methods: ==

    def check(self, c: CycleCheck) -> Trip | None:
        """The most severe new trip of this cycle (None when all is well or already latched)."""
        found = self._find(
            c.t_s,
            c.dt_s,
            c.q_cmd_mm,
            c.q_prev_mm,
            c.tension_N,
            c.tension_age_s,
            c.tip_error_mm,
            c.tip_age_s,
            c.moving,
            c.retensioning,
        )
        for extra in self.extra_checks:
            trip = extra(c)
            if trip is not None:
                found.append(trip)
        return self._settle(found)

    def check_cycle(
        self,
        t_s: float,
        dt_s: float,
        q_cmd_mm: Sequence[float],
        q_prev_mm: Sequence[float],
        tension_N: Sequence[float] = (),
        tension_age_s: Sequence[float] = (),
        tip_error_mm: float = math.nan,
        tip_age_s: float = math.inf,
        moving: bool = True,
        retensioning: Sequence[bool] = (),
    ) -> Trip | None:
        """:meth:`check` of ``CycleCheck(t_s, dt_s, ...)`` (the same fields, the same result and
        latching); the record is made only for the :attr:`extra_checks` (the loop's every cycle
        without them makes none), with copies of the lists (the caller keeps using its own)."""
        found = self._find(
            t_s,
            dt_s,
            q_cmd_mm,
            q_prev_mm,
            tension_N,
            tension_age_s,
            tip_error_mm,
            tip_age_s,
            moving,
            retensioning,
        )
        if self.extra_checks:
            c = CycleCheck(
                t_s,
                dt_s,
                list(q_cmd_mm),
                list(q_prev_mm),
                list(tension_N),
                list(tension_age_s),
                tip_error_mm,
                tip_age_s,
                moving,
                tuple(retensioning),
            )
            for extra in self.extra_checks:
                trip = extra(c)
                if trip is not None:
                    found.append(trip)
        return self._settle(found)

    def _settle(self, found: list[Trip]) -> Trip | None:
        """Latch the worst of this cycle's ``found`` trips (see :meth:`check`)."""
        if not found:
            self.cycle_worst = None
            return None
        worst = max(found, key=lambda t: t.reaction)
        self.cycle_worst = worst
        if self.trip is None:
            self.trip = worst
            self.history.append(worst)
            return worst
        if worst.reaction > self.trip.reaction:
            # Escalate (e.g. a hold followed by an overload): the stronger reaction wins.
            self.trip = worst
            self.history.append(worst)
            return worst
        self.later_trips += 1
        return None

    def external(self, cause: str, reaction: Reaction, detail: str, t_s: float) -> Trip | None:
        """A trip from outside the per-cycle checks: drive EMCY, heartbeat loss, bus, log."""
        trip = Trip(cause, reaction, detail, t_s)
        if self.trip is None or reaction > self.trip.reaction:
            self.trip = trip
            self.history.append(trip)
            return trip
        self.later_trips += 1
        return None

    def reset(self) -> None:
        """Operator acknowledges the trip; the history is kept."""
        self.trip = None

    def _find(
        self,
        t_s: float,
        dt_s: float,
        q_cmd_mm: Sequence[float],
        q_prev_mm: Sequence[float],
        tension_N: Sequence[float],
        tension_age_s: Sequence[float],
        tip_error_mm: float,
        tip_age_s: float,
        moving: bool,
        retensioning: Sequence[bool] = (),
    ) -> list[Trip]:
        """The limits the cycle's values (the fields of :class:`CycleCheck`) violate."""
        lim = self.limits
        out: list[Trip] = []
        lo, hi = lim.cable_displacement_mm
        vmax = lim.cable_velocity_mm_s
        for k, q in enumerate(q_cmd_mm):
            if not math.isfinite(q):
                out.append(Trip(f"command_invalid:cable{k + 1}", Reaction.HALT, f"q_cmd={q}", t_s))
            elif q < lo or q > hi:
                out.append(
                    Trip(
                        f"displacement_limit:cable{k + 1}",
                        Reaction.HOLD,
                        f"q_cmd {q:.3f} mm outside [{lo}, {hi}] mm",
                        t_s,
                    )
                )
            if dt_s > 0 and k < len(q_prev_mm) and math.isfinite(q):
                v = abs(q - q_prev_mm[k]) / dt_s
                if v > vmax:
                    out.append(
                        Trip(
                            f"velocity_limit:cable{k + 1}",
                            Reaction.HALT,
                            f"{v:.1f} mm/s above {vmax} mm/s",
                            t_s,
                        )
                    )
        if self.use_tension:
            t_lo, t_hi = lim.tension_N
            for k, (f, age) in enumerate(zip(tension_N, tension_age_s, strict=False)):
                if not (age <= lim.sensor_timeout_s):
                    if not moving:
                        continue  # idle: reported in status, tripped on only while moving
                    out.append(
                        Trip(
                            f"stale_tension:cable{k + 1}",
                            Reaction.HALT,
                            f"load-cell sample {age:.3f} s old (limit {lim.sensor_timeout_s} s)",
                            t_s,
                        )
                    )
                    continue
                if f > t_hi:
                    out.append(
                        Trip(
                            f"tension_high:cable{k + 1}",
                            Reaction.QUICK_STOP,
                            f"{f:.2f} N above {t_hi} N",
                            t_s,
                        )
                    )
                elif f < t_lo and moving and not (k < len(retensioning) and retensioning[k]):
                    out.append(
                        Trip(
                            f"tension_low:cable{k + 1}",
                            Reaction.HOLD,
                            f"{f:.2f} N below {t_lo} N (slack)",
                            t_s,
                        )
                    )
        if self.use_tracker:
            if not (tip_age_s <= lim.sensor_timeout_s):
                if not moving:
                    return out
                out.append(
                    Trip(
                        "stale_tracker",
                        Reaction.HALT,
                        f"tracker sample {tip_age_s:.3f} s old (limit {lim.sensor_timeout_s} s)",
                        t_s,
                    )
                )
            elif tip_error_mm > lim.tracker_divergence_mm:
                out.append(
                    Trip(
                        "tracker_divergence",
                        Reaction.HALT,
                        f"tip {tip_error_mm:.1f} mm from model"
                        f" (limit {lim.tracker_divergence_mm} mm)",
                        t_s,
                    )
                )
        return out
