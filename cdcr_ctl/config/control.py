"""Control-loop, limit, logging and daemon sections of the rig config."""

from __future__ import annotations

import ipaddress
import math
import os
import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_serializer, field_validator, model_validator

from cdcr_ctl.config.base import Section, Timeout


class ModelEffectsConfig(Section):
    """Which effects the controller's model (the ``cc_disk`` compensation) includes.

    Each switch is an effect of Qi et al. 2023 the compensation can leave out: ``disk_friction``
    (capstan friction in the disk holes, eq. 16-24), ``pulley_friction`` (eq. 25-32),
    ``elongation`` (elastic cables, eq. 33-36; off: rigid), ``coupling`` (distal cables load the
    proximal segments, eq. 11-15), ``gravity`` (disk weights). ``coupling_gain``: weight of the
    distal cables' load on the proximal segments when ``coupling`` is on (1 as derived; a fitted
    value from the discrepancy workflow otherwise), dimensionless in [0, 2].
    """

    disk_friction: bool = True
    pulley_friction: bool = True
    elongation: bool = True
    coupling: bool = True
    gravity: bool = True
    coupling_gain: Annotated[float, Field(ge=0, le=2, allow_inf_nan=False)] = 1.0


class ControlConfig(Section):
    """The real-time loop.

    ``compensation``: ``off`` sends the ideal inverse kinematics; ``model`` adds the force-transfer
    feedforward delta of Qi et al. 2023 eq. 37 from modelled tensions; ``measured`` uses the
    load-cell tensions in place of modelled ones.
    """

    #: Loop rate (Hz); the drives follow the SYNC, whose period is ``can.sync_period_s``.
    rate_hz: Annotated[float, Field(gt=0, le=4000)] = 1000.0
    compensation: Literal["off", "model", "measured"] = "model"

    @field_validator("compensation", mode="before")
    @classmethod
    def _yaml_off(cls, value: object) -> object:
        # YAML 1.1 reads a bare `off` as false: accept it as the mode it was meant to be.
        return "off" if value is False else value

    #: Cable geometry of the model: ``chord`` the straight spans between disk holes (exact for a
    #: disk robot), ``cc`` the continuous routing of Qi et al. 2023 eq. 4.
    geometry: Literal["chord", "cc"] = "chord"
    #: Actuator travel over which friction reverses in the compensation (0: the model's stick rule).
    reversal_band_mm: Annotated[float, Field(ge=0, le=10)] = 0.0
    #: Effects of the controller's model (switches and the coupling gain), all on by default.
    model_effects: ModelEffectsConfig = Field(default_factory=ModelEffectsConfig)
    #: SCHED_FIFO priority of the loop's threads (0: ordinary scheduling); needs ``LimitRTPRIO`` or
    #: root.
    realtime_priority: Annotated[int, Field(ge=0, le=99)] = 0
    #: Lock the daemon's memory (``mlockall``) so the loop never waits on a page fault; needs
    #: ``LimitMEMLOCK``.
    lock_memory: bool = False


#: Physical bounds on the limits themselves: a limit beyond them is a typo, not a rig. Each says
#: why; a limit is the supervisor's promise, and ``.inf`` or 1e6 promises nothing.
#:
#: Cable velocity (mm/s): 1 m/s is several times what a capstan or lead-screw drive of a continuum
#: arm reaches (the shipped rigs use 10-50 mm/s); beyond it a runaway is not caught.
CABLE_VELOCITY_MAX_MM_S = 1000.0
#: Cable displacement (mm, either sign): 1 m is more than the cable travel of any arm this
#: controller serves (the longest, the universal-joint arm, uses +-60 mm of its 2.9 m cables).
CABLE_DISPLACEMENT_MAX_MM = 1000.0
#: Cable tension (N): 5 kN is above the breaking load of 2 mm steel wire rope (~2.5-3 kN); the
#: shipped rigs stop at 60-400 N.
TENSION_MAX_N = 5000.0
#: Segment bend (rad): a segment bends at most half a turn before it touches itself.
BEND_MAX_RAD = math.pi
#: Tracker divergence (mm): beyond 1 m the check cannot tell a wrong arm from a right one.
DIVERGENCE_MAX_MM = 1000.0


class LimitsConfig(Section):
    """Safety limits, checked every cycle by the supervisor (bounds: the constants above)."""

    #: Cable displacement window [min, max] from straight; a command outside it is
    #: held (``displacement_limit``, HOLD).
    cable_displacement_mm: Annotated[
        list[
            Annotated[
                float,
                Field(
                    ge=-CABLE_DISPLACEMENT_MAX_MM,
                    le=CABLE_DISPLACEMENT_MAX_MM,
                    allow_inf_nan=False,
                ),
            ]
        ],
        Field(min_length=2, max_length=2),
    ] = Field(default_factory=lambda: [-20.0, 20.0])
    #: Fastest a commanded cable may move; faster trips
    #: ``velocity_limit`` (HALT).
    cable_velocity_mm_s: Annotated[
        float, Field(gt=0, le=CABLE_VELOCITY_MAX_MM_S, allow_inf_nan=False)
    ] = 50.0
    #: Cable tension window [slack, max]: below the first the command is held (slack), above the
    #: second the rig trips ``tension_high``.
    tension_N: Annotated[
        list[Annotated[float, Field(ge=-TENSION_MAX_N, le=TENSION_MAX_N, allow_inf_nan=False)]],
        Field(min_length=2, max_length=2),
    ] = Field(default_factory=lambda: [0.2, 60.0])
    #: Largest segment bend a command or trajectory may ask for.
    bend_rad: Annotated[float, Field(gt=0, le=BEND_MAX_RAD, allow_inf_nan=False)] = 2.0
    #: Tracked tip further than this from the model tip of the command trips ``tracker_divergence``
    #: (HALT).
    tracker_divergence_mm: Annotated[
        float, Field(gt=0, le=DIVERGENCE_MAX_MM, allow_inf_nan=False)
    ] = 30.0
    #: A load-cell or tracker sample older than this trips ``stale_tension`` / ``stale_tracker``
    #: (HALT).
    sensor_timeout_s: Timeout = 0.2

    @model_validator(mode="after")
    def _ordered(self) -> LimitsConfig:
        for key in ("cable_displacement_mm", "tension_N"):
            lo, hi = getattr(self, key)
            if lo >= hi:
                raise ValueError(f"{key} must be [min, max] with min < max")
        return self


class LoggingConfig(Section):
    """Run logs: one directory per run below ``directory``.

    ``directory``: where the run directories go. A relative path is relative to the working
    directory of the process that writes the logs (the daemon's; under the systemd unit
    ``/var/lib/cdcr-ctl``), not to the config file. Not set: ``$STATE_DIRECTORY/runs`` when
    systemd gives a state directory (the unit's ``StateDirectory=``: ``/var/lib/cdcr-ctl/runs``),
    else ``runs`` in the working directory (:func:`run_log_dir`).
    """

    directory: str | None = None
    #: A deleted run directory or a full disk is seen within one interval: beyond 10 s a lost
    #: log goes unseen for too long.
    fsync_every_s: Timeout = 0.5
    #: Also write the run as ``run.mcap`` (Foxglove, PlotJuggler): one channel per stream, zstd
    #: chunks closed and flushed every ``fsync_every_s``. ``samples.csv`` is written either way.
    mcap: bool = True
    #: Where the rows are encoded and written: ``process`` (a writer process of its own; the
    #: loop only copies each row's numbers into shared memory, so the encoding never holds the
    #: loop's interpreter lock) or ``thread`` (a thread of the daemon).
    writer: Literal["process", "thread"] = "process"
    #: Rows the loop may hand over before the writer has taken them, in seconds of the loop's
    #: rate (the shared-memory ring of ``writer: process``, the queue of ``writer: thread``).
    #: In real time a full ring trips ``log_overflow`` (quick stop, the log kept) rather than
    #: drop rows unseen; a loop on simulated time (lock-step) waits for the writer instead.
    #: The writer process under a 2-core ``stress-ng --cpu 2`` held at most ~1 s of a 1 kHz
    #: loop's rows (benchmarks/bench_loop.py), so 10 s is a tenfold margin for ~14 MB of memory.
    ring_s: Annotated[float, Field(gt=0, le=60)] = 10.0
    #: The ring of a loop on simulated time (lock-step), in seconds of simulated time at the
    #: loop's rate: its writer drains it only once it is half full or the run ends
    #: (``cdcr_ctl.runlog.writer.spawn.WAIT_DEFER_FILL``), so a run up to half this long is
    #: written after its last cycle, not beside it. 60 s at 250 Hz is 15 000 rows (~3 MB of
    #: numbers touched; the event text area is touched only by rows with an event).
    wait_ring_s: Annotated[float, Field(gt=0, le=600)] = 60.0


class LiveViewConfig(Section):
    """The live view: the loop's channels over the Foxglove WebSocket protocol while it runs.

    Off unless ``enabled``. There is no authentication, so the server binds ``host``
    (127.0.0.1 unless the config names another address). ``rate_hz``: messages per second on
    each sample channel (commands, cables, tensions, tips, loop timing), taken from the latest
    cycle; ``scene_hz``: backbone 3D scene updates per second.
    """

    enabled: bool = False
    host: str = "127.0.0.1"
    #: TCP port of the Foxglove WebSocket server (0: any free port).
    port: Annotated[int, Field(ge=0, le=65535)] = 8765
    rate_hz: Annotated[float, Field(gt=0, le=200)] = 50.0
    scene_hz: Annotated[float, Field(gt=0, le=60)] = 10.0

    @field_validator("host")
    @classmethod
    def _address(cls, value: str) -> str:
        # An IP address, not a name: what the server listens on must be plain in the config.
        try:
            ipaddress.ip_address(value)
        except ValueError:
            raise ValueError(f"{value!r} is not an IP address (e.g. 127.0.0.1)") from None
        return value


class DaemonConfig(Section):
    """The daemon's control socket (Unix domain, mode 0660; no TCP listener).

    ``socket_mode``: owner read-write at least (the daemon's own user must reach it), nothing for
    others (whoever connects can move the arm; widen access with the socket's group instead).
    """

    #: The control socket the CLI talks to; under systemd ``/run/cdcr-ctl`` is the unit's runtime
    #: directory.
    socket_path: str = "/run/cdcr-ctl/control.sock"
    socket_mode: Annotated[int, Field(ge=0o600, le=0o770)] = 0o660
    #: Pet systemd's watchdog (``WatchdogSec=``) while the loop runs.
    watchdog: bool = True

    @field_validator("socket_mode", mode="before")
    @classmethod
    def _octal_text(cls, value: object) -> object:
        # A dumped config writes the mode as text, "0o660" (YAML 1.1 reads 0660 as octal, but
        # the integer 432 it becomes reads as nothing); both load.
        if isinstance(value, str) and re.fullmatch(r"0o?[0-7]{3,4}", value.strip()):
            return int(value.strip().removeprefix("0o"), 8)
        return value

    @field_serializer("socket_mode", when_used="json")
    def _octal(self, value: int) -> str:
        return f"{value:#o}"

    @field_validator("socket_mode")
    @classmethod
    def _not_for_others(cls, value: int) -> int:
        if value & 0o007:
            raise ValueError(
                f"{value:#o} gives others access: anyone could move the arm (at most 0o770)"
            )
        if value & 0o600 != 0o600:
            raise ValueError(f"{value:#o}: the owner needs read and write (0o600)")
        return value


def run_log_dir(logging_cfg: LoggingConfig, env: dict[str, str] | None = None) -> Path:
    """The directory run logs go to (see :class:`LoggingConfig`), absolute: ``directory``
    against the working directory, else ``$STATE_DIRECTORY/runs`` (its first entry), else
    ``./runs``. ``env``: the environment to read (default ``os.environ``)."""
    env = os.environ if env is None else env
    if logging_cfg.directory:
        return Path(os.path.abspath(os.path.expanduser(logging_cfg.directory)))
    state = env.get("STATE_DIRECTORY", "").split(":")[0]
    if state:
        return Path(os.path.abspath(state)) / "runs"
    return Path(os.path.abspath("runs"))
