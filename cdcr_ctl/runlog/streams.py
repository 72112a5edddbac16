"""The run log's streams as channels: one topic per stream, a JSON Schema per topic with units.

Shared by the MCAP run log (:mod:`cdcr_ctl.runlog.mcap_sink`), its reader
(:mod:`cdcr_ctl.runlog.mcap_reader`) and the live view (:mod:`cdcr_ctl.runlog.live`), so a
topic means the same in a file and on the wire. Messages are JSON (``json`` message encoding,
``jsonschema`` schema encoding): Foxglove and PlotJuggler decode them without plug-ins. Units are
in every field name and in its schema ``description``; a missing measurement is ``null``.
Arrays are indexed by segment ``i`` or cable ``k`` from 0 in the order of ``robot.segments`` and
``robot.cables`` of the rig config (the CSV columns number them from 1).

=================  ===================  ==============================================  ==========
topic              schema               fields                                          per
=================  ===================  ==============================================  ==========
``/command``       ``cdcr.Command``     θ, φ per segment (rad); q nominal, q sent (mm)  cycle
``/cables``        ``cdcr.Cables``      q actual from drive feedback (mm)               cycle
``/tension``       ``cdcr.Tension``     load-cell tension per cable (N)                 cycle
``/tip/tracked``   ``cdcr.Tip``         tracked tip, robot base frame (mm)              cycle
``/tip/model``     ``cdcr.ModelTip``    model tip of the command (mm), its distance     see below
                                        to the tracked tip of the same cycle (mm)
``/loop``          ``cdcr.LoopTiming``  cycle number, lateness (µs)                     cycle
``/events``        ``cdcr.Event``       supervisor events and trips (text)              event
``/extra``         ``cdcr.Extra``       any further column of the run (name -> value)   cycle
``/can``           ``cdcr.CanFrame``    raw CAN frame (id, flags, data as hex)          frame
=================  ===================  ==============================================  ==========

Every message carries ``t_s`` (loop time, s) and ``cycle`` (loop cycle counter) so a reader
joins the channels by cycle; a ``/can`` frame's are those of the last row written before it
(:meth:`~cdcr_ctl.runlog.mcap_sink.McapSink.write_can`), its own time is ``timestamp_s``.
``docs/operating/channels.md`` documents the channels (a test holds it to the files).
``/tip/model`` is written every :func:`model_tip_every` cycles
(at most :data:`MODEL_TIP_MAX_HZ`): the forward kinematics of some designs costs more than a
cycle can spare, and the writer thread must keep up with the loop. Its message is made in
:mod:`cdcr_ctl.runlog.model_tip` (numpy), apart: this module imports no numpy, so the run-log
writer process starts without it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from cdcr_ctl.runlog.columns import (
    LOOP_EXTRA_COLUMNS,
    TIME,
    TIP_COLUMNS,
    cable_column,
    counts_from_columns,
    phi_cmd,
    theta_cmd,
)

COMMAND = "/command"
CABLES = "/cables"
TENSION = "/tension"
TIP_TRACKED = "/tip/tracked"
TIP_MODEL = "/tip/model"
LOOP = "/loop"
EVENTS = "/events"
EXTRA = "/extra"
CAN = "/can"
#: Backbone 3D scene (live view only; foxglove.SceneUpdate).
SCENE = "/scene/backbone"

#: Highest rate of ``/tip/model`` messages (Hz).
MODEL_TIP_MAX_HZ = 100.0

TipFromPsi = Callable[[Any], Any]


def _num(description: str) -> dict[str, Any]:
    return {"type": ["number", "null"], "description": description}


def _arr(description: str) -> dict[str, Any]:
    return {"type": "array", "items": {"type": ["number", "null"]}, "description": description}


_T = {"type": "number", "description": "s: loop time of the cycle (monotonic, 0 at loop start)"}
_CYCLE = {"type": "integer", "description": "loop cycle counter"}


def _schema(title: str, props: dict[str, Any]) -> dict[str, Any]:
    return {
        "title": title,
        "type": "object",
        "properties": {"t_s": _T, "cycle": _CYCLE, **props},
    }


#: topic -> (schema name, JSON Schema)
SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    COMMAND: (
        "cdcr.Command",
        _schema(
            "Commanded pose and cable displacements",
            {
                "theta_rad": _arr("rad: commanded bend angle θ per segment"),
                "phi_rad": _arr("rad: commanded bending-plane direction φ per segment"),
                "q_nominal_mm": _arr("mm: ideal inverse kinematics per cable, pulled in > 0"),
                "q_cmd_mm": _arr("mm: after compensation, sent to the drive, per cable"),
            },
        ),
    ),
    CABLES: (
        "cdcr.Cables",
        _schema(
            "Cable displacements from drive feedback",
            {"q_act_mm": _arr("mm: drive position feedback per cable, pulled in > 0")},
        ),
    ),
    TENSION: (
        "cdcr.Tension",
        _schema("Cable tensions", {"tension_N": _arr("N: load-cell tension per cable")}),
    ),
    TIP_TRACKED: (
        "cdcr.Tip",
        _schema(
            "Tracked tip in the robot base frame",
            {
                "x_mm": _num("mm: tip x, robot base frame"),
                "y_mm": _num("mm: tip y, robot base frame"),
                "z_mm": _num("mm: tip z, robot base frame"),
            },
        ),
    ),
    TIP_MODEL: (
        "cdcr.ModelTip",
        _schema(
            "Model tip of the commanded pose and its distance to the tracked tip",
            {
                "x_mm": _num("mm: model tip x, robot base frame"),
                "y_mm": _num("mm: model tip y, robot base frame"),
                "z_mm": _num("mm: model tip z, robot base frame"),
                "error_mm": _num("mm: |tracked - model| tip of the same cycle (no lag model)"),
            },
        ),
    ),
    LOOP: (
        "cdcr.LoopTiming",
        _schema("Loop timing", {"lateness_us": _num("µs: cycle start after its deadline")}),
    ),
    EVENTS: (
        "cdcr.Event",
        _schema("Supervisor event or trip", {"event": {"type": "string"}}),
    ),
    EXTRA: (
        "cdcr.Extra",
        _schema(
            "Further columns of the run (units in the names)",
            {"values": {"type": "object", "additionalProperties": True}},
        ),
    ),
    CAN: (
        "cdcr.CanFrame",
        {
            "title": "Raw CAN frame",
            "type": "object",
            "properties": {
                "t_s": {
                    "type": ["number", "null"],
                    "description": "s: loop time of the last row logged before the frame"
                    " was written (its own time: timestamp_s)",
                },
                "cycle": {
                    "type": "integer",
                    "description": "loop cycle counter of the last row logged before the frame"
                    " was written (-1 before the first)",
                },
                "timestamp_s": {
                    "type": "number",
                    "description": "s: UNIX time of the frame (0: the bus did not stamp it)",
                },
                "id": {"type": "integer", "description": "arbitration id"},
                "extended": {"type": "boolean"},
                "rx": {"type": "boolean", "description": "received (else sent by us)"},
                "error": {"type": "boolean"},
                "remote": {"type": "boolean"},
                "dlc": {"type": "integer"},
                "data": {"type": "string", "description": "payload bytes as hex"},
            },
        },
    ),
}

#: Topics with one message per logged cycle.
PER_CYCLE = (COMMAND, CABLES, TENSION, TIP_TRACKED, LOOP)


def schema_bytes(topic: str) -> bytes:
    return json.dumps(SCHEMAS[topic][1], separators=(",", ":")).encode()


def model_tip_every(rate_hz: float | None) -> int:
    """Cycles between two ``/tip/model`` messages at loop rate ``rate_hz`` (Hz)."""
    if not rate_hz or rate_hz <= MODEL_TIP_MAX_HZ:
        return 1
    return math.ceil(rate_hz / MODEL_TIP_MAX_HZ)


def _clean(v: Any) -> Any:
    """JSON value: NaN/inf -> null, numpy scalars -> Python."""
    if v is None or isinstance(v, str | bool | int):
        return v
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return f if math.isfinite(f) else None


_float_text = float.__repr__


def _num_text(v: Any) -> str:
    """JSON text of one number: the shortest exact repr; ``null`` for None, NaN, inf."""
    if type(v) is float:
        return _float_text(v) if v - v == 0.0 else "null"  # NaN - NaN, inf - inf: NaN
    c = _clean(v)
    if c is None:
        return "null"
    return json.dumps(c)


@dataclass(frozen=True)
class RowStreams:
    """Turns run-log rows (the CSV's columns) into channel messages.

    ``columns``: the run's columns (see :func:`~cdcr_ctl.runlog.columns.sample_columns`).
    """

    columns: tuple[str, ...]

    @property
    def counts(self) -> tuple[int, int]:
        return counts_from_columns(self.columns)

    def __post_init__(self) -> None:
        S, K = counts_from_columns(self.columns)
        cols = set(self.columns)
        known = {TIME, *LOOP_EXTRA_COLUMNS, *TIP_COLUMNS}
        known |= {theta_cmd(i) for i in range(1, S + 1)} | {phi_cmd(i) for i in range(1, S + 1)}
        for g in ("q_nominal", "q_cmd", "q_act", "tension"):
            known |= {cable_column(g, k) for k in range(1, K + 1)}
        object.__setattr__(self, "_extra", tuple(c for c in self.columns if c not in known))
        object.__setattr__(self, "_has_cycle", "cycle" in cols)
        rs, rk = range(1, S + 1), range(1, K + 1)
        names = {
            "theta": [theta_cmd(i) for i in rs],
            "phi": [phi_cmd(i) for i in rs],
            **{g: [cable_column(g, k) for k in rk] for g in ("q_nominal", "q_cmd", "q_act")},
            "tension": [cable_column("tension", k) for k in rk],
        }
        object.__setattr__(self, "_names", names)

    def as_dict(self, row: Mapping[str, Any] | Sequence[Any]) -> dict[str, Any]:
        if isinstance(row, dict):
            return row
        if isinstance(row, Mapping):
            as_columns = getattr(row, "columns", None)  # the loop's CycleRow: its cached dict
            return as_columns() if callable(as_columns) else dict(row.items())
        return dict(zip(self.columns, row, strict=False))

    def encoded(self, d: Mapping[str, Any], n: int) -> list[tuple[str, bytes]]:
        """What :meth:`messages` gives, as the JSON bytes :func:`encode` makes of it, built as
        text directly (the writer thread's cost per row; a test holds the two equal)."""
        g = d.get
        cyc = g("cycle") if self._has_cycle else n
        cyc = int(cyc) if cyc is not None and cyc == cyc else n
        head = f'{{"t_s":{_num_text(g(TIME))},"cycle":{cyc}'
        nm = self._names

        def arr(key: str) -> str:
            # _num_text inlined for finite floats (almost every value): the same text.
            return ",".join(
                [
                    _float_text(v) if type(v) is float and v - v == 0.0 else _num_text(v)
                    for v in map(g, nm[key])
                ]
            )

        out = [
            (
                COMMAND,
                f'{head},"theta_rad":[{arr("theta")}],"phi_rad":[{arr("phi")}],'
                f'"q_nominal_mm":[{arr("q_nominal")}],"q_cmd_mm":[{arr("q_cmd")}]}}',
            ),
            (CABLES, f'{head},"q_act_mm":[{arr("q_act")}]}}'),
            (TENSION, f'{head},"tension_N":[{arr("tension")}]}}'),
            (
                TIP_TRACKED,
                f'{head},"x_mm":{_num_text(g("tip_x_mm"))},"y_mm":{_num_text(g("tip_y_mm"))},'
                f'"z_mm":{_num_text(g("tip_z_mm"))}}}',
            ),
            (LOOP, f'{head},"lateness_us":{_num_text(g("lateness_us"))}}}'),
        ]
        event = g("event")
        if event:
            out.append((EVENTS, f'{head},"event":{json.dumps(str(event))}}}'))
        if self._extra:
            values = {c: _clean(g(c)) for c in self._extra}
            out.append((EXTRA, f'{head},"values":{json.dumps(values, allow_nan=False)}}}'))
        return [(topic, text.encode()) for topic, text in out]

    def messages(self, d: Mapping[str, Any], n: int) -> list[tuple[str, dict[str, Any]]]:
        """(topic, message) of one row ``d``; ``n`` is the row's index in the run (its cycle
        when the row has no ``cycle`` column)."""
        S, K = self.counts
        g = d.get
        t = _clean(g(TIME))
        cyc = g("cycle") if self._has_cycle else n
        cyc = int(cyc) if cyc is not None and cyc == cyc else n
        head = {"t_s": t, "cycle": cyc}
        rng_s, rng_k = range(1, S + 1), range(1, K + 1)
        out = [
            (
                COMMAND,
                {
                    **head,
                    "theta_rad": [_clean(g(theta_cmd(i))) for i in rng_s],
                    "phi_rad": [_clean(g(phi_cmd(i))) for i in rng_s],
                    "q_nominal_mm": [_clean(g(cable_column("q_nominal", k))) for k in rng_k],
                    "q_cmd_mm": [_clean(g(cable_column("q_cmd", k))) for k in rng_k],
                },
            ),
            (CABLES, {**head, "q_act_mm": [_clean(g(cable_column("q_act", k))) for k in rng_k]}),
            (
                TENSION,
                {**head, "tension_N": [_clean(g(cable_column("tension", k))) for k in rng_k]},
            ),
            (
                TIP_TRACKED,
                {**head, "x_mm": _clean(g("tip_x_mm")), "y_mm": _clean(g("tip_y_mm")),
                 "z_mm": _clean(g("tip_z_mm"))},
            ),
            (LOOP, {**head, "lateness_us": _clean(g("lateness_us"))}),
        ]  # fmt: skip
        event = g("event")
        if event:
            out.append((EVENTS, {**head, "event": str(event)}))
        if self._extra:
            out.append((EXTRA, {**head, "values": {c: _clean(g(c)) for c in self._extra}}))
        return out


def encode(msg: Mapping[str, Any]) -> bytes:
    """One message as compact JSON (floats as their shortest exact repr)."""
    return json.dumps(msg, separators=(",", ":"), allow_nan=False).encode()
