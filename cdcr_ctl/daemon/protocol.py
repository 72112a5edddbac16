"""Control-socket protocol: newline-delimited JSON requests and replies over a Unix socket.

Request: ``{"cmd": "<name>", "args": {...}, "id": <int>}``; reply:
``{"id": <int>, "ok": true, "result": {...}}`` or ``{"id": <int>, "ok": false, "error": "...",
"field": "args.theta_rad"}``. Every request is validated against the model of its command before
anything moves; an error names the field at fault.

Limits (each refusal names its limit):

- a request line is at most :data:`MAX_LINE_BYTES`; a longer one is read to its end, discarded
  and refused;
- lines above :data:`INLINE_PARSE_BYTES` are parsed and validated in the daemon's intake process,
  never in the process of the control loop (:mod:`cdcr_ctl.daemon.intake`);
- a trajectory has at most :data:`MAX_TRAJECTORY_SAMPLES` samples; longer or bigger ones go as a
  ``file`` the daemon reads and validates in its intake process;
- ``id`` is an integer of at most :data:`MAX_ID_DIGITS` digits;
- jog speeds and move lengths are bounded from the rig config's limits
  (:func:`jog_speed_bounds`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from cdcr_ctl.errors import RigError

#: Longest request line accepted (a 10-minute trajectory at 100 Hz for 3 segments fits easily).
MAX_LINE_BYTES = 16 * 1024 * 1024
#: Request lines longer than this are parsed in the intake process (a JSON parse holds the
#: interpreter for ~10 ms per MB: not in the loop's process).
INLINE_PARSE_BYTES = 64 * 1024
#: Most samples of one trajectory (inline or from a file): 10^6 rows is 16 min at 1 kHz.
MAX_TRAJECTORY_SAMPLES = 2_000_000
#: Longest request ``id`` (digits): any 64-bit integer.
MAX_ID_DIGITS = 19
#: Longest jog move (s) and its sample spacing (s): a jog's samples are bounded by their ratio.
MAX_JOG_DURATION_S = 600.0
JOG_DT_S = 0.01
#: Fastest jog (rad/s of bend), also the protocol's bound.
MAX_JOG_SPEED_RAD_S = 10.0

Finite = Annotated[float, Field(allow_inf_nan=False)]


class ProtocolError(RigError):
    """A request that cannot be accepted; ``field`` names the part at fault."""

    def __init__(self, message: str, field: str = "") -> None:
        self.field = field
        super().__init__(f"{field}: {message}" if field else message)


class _Args(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class NoArgs(_Args):
    pass


class JogArgs(_Args):
    """Jog one segment to (theta, phi) or one cable by ``delta_mm``, at a bounded speed.

    Segment and cable numbers start at 1, like the log columns.
    """

    segment: Annotated[int, Field(ge=1, le=16)] | None = None
    theta_rad: Finite | None = None
    phi_rad: Finite | None = None
    cable: Annotated[int, Field(ge=1, le=64)] | None = None
    delta_mm: Finite | None = None
    speed: Annotated[float, Field(gt=0, le=MAX_JOG_SPEED_RAD_S, allow_inf_nan=False)] = 0.3

    @model_validator(mode="after")
    def _one_target(self) -> JogArgs:
        seg = self.segment is not None
        cab = self.cable is not None
        if seg == cab:
            raise ValueError("give either segment (+ theta_rad, phi_rad) or cable (+ delta_mm)")
        if seg and (self.theta_rad is None or self.phi_rad is None):
            raise ValueError("a segment jog needs theta_rad and phi_rad")
        if cab and self.delta_mm is None:
            raise ValueError("a cable jog needs delta_mm")
        return self


class TrajectoryArgs(_Args):
    """A trajectory to run: timed samples ``[t_s, seg1_theta, seg1_phi, ...]`` inline, or a
    ``file`` (CSV or YAML, an absolute path the daemon can read) for big ones; validated again
    by the daemon against the rig. A name for the log, and the compensation mode of the run."""

    name: Annotated[str, Field(min_length=1, max_length=200)]
    samples: (
        Annotated[
            list[Annotated[list[Finite], Field(min_length=3, max_length=33)]],
            Field(min_length=2, max_length=MAX_TRAJECTORY_SAMPLES),
        ]
        | None
    ) = None
    file: Annotated[str, Field(min_length=1, max_length=4096)] | None = None
    compensation: Literal["off", "model", "measured"] | None = None
    log: bool = True

    @model_validator(mode="after")
    def _one_source(self) -> TrajectoryArgs:
        if (self.samples is None) == (self.file is None):
            raise ValueError("give either samples or file")
        if self.file is not None and not self.file.startswith("/"):
            raise ValueError("file must be an absolute path (the daemon has its own directory)")
        return self


class JoystickArgs(_Args):
    """A live joystick end-following session (vertebra arm): ``seconds`` limit (None: until
    ``stop``), compensation mode of the run, log it (run directory like a trajectory's),
    run name for the log."""

    seconds: Annotated[float, Field(gt=0, le=24 * 3600, allow_inf_nan=False)] | None = None
    compensation: Literal["off", "model", "measured"] | None = None
    log: bool = True
    name: Annotated[str, Field(min_length=1, max_length=200)] = "joystick"


class StopArgs(_Args):
    mode: Literal["halt", "quick_stop"] = "quick_stop"


class LogStartArgs(_Args):
    name: Annotated[str, Field(min_length=1, max_length=200)] = "manual"


class CompensationArgs(_Args):
    mode: Literal["off", "model", "measured"]


class FaultArgs(_Args):
    """Simulator fault injection is not on this socket; this resets a latched supervisor fault."""

    confirm: bool = False


#: Command name -> argument model.
COMMANDS: dict[str, type[_Args]] = {
    "status": NoArgs,
    "enable": NoArgs,
    "disable": NoArgs,
    "home": NoArgs,
    "jog": JogArgs,
    "trajectory": TrajectoryArgs,
    "joystick": JoystickArgs,
    "stop": StopArgs,
    "log_start": LogStartArgs,
    "log_stop": NoArgs,
    "compensation": CompensationArgs,
    "reset_fault": FaultArgs,
    "shutdown": NoArgs,
}


class Request(BaseModel):
    model_config = ConfigDict(frozen=True)

    id: int
    cmd: str
    args: _Args


def _bounded_int(text: str) -> int:
    """JSON integers of at most :data:`MAX_ID_DIGITS` digits (a longer one is refused, not
    converted: Python's conversion of a 5000-digit number raises)."""
    if len(text.lstrip("-")) > MAX_ID_DIGITS:
        raise ProtocolError(f"integer of {len(text)} characters: at most {MAX_ID_DIGITS} digits")
    return int(text)


def jog_speed_bounds(bend_rad: float) -> tuple[float, float]:
    """Slowest and fastest jog speed (rad/s) for a rig whose ``limits.bend_rad`` is ``bend_rad``:
    the slowest crosses the whole bend range (2 ``bend_rad`` in bending vectors) in
    :data:`MAX_JOG_DURATION_S`, so a jog has at most ``MAX_JOG_DURATION_S / JOG_DT_S`` samples."""
    return (math.pi * bend_rad / MAX_JOG_DURATION_S, MAX_JOG_SPEED_RAD_S)


def check_jog_speed(speed: float, bend_rad: float) -> None:
    """Refuse a jog speed outside :func:`jog_speed_bounds`, naming the limit."""
    lo, hi = jog_speed_bounds(bend_rad)
    if not lo <= speed <= hi:
        raise ProtocolError(
            f"{speed!r} rad/s outside [{lo:.4g}, {hi:g}] rad/s (slowest: the whole bend range"
            f" of limits.bend_rad = {bend_rad:g} rad in {MAX_JOG_DURATION_S:g} s)",
            field="args.speed",
        )


def _field(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else ("." if out else "") + str(part)
    return out


def parse_request(line: bytes | str) -> Request:
    """Decode and validate one request line; raise :class:`ProtocolError` naming the field."""
    if isinstance(line, bytes):
        if len(line) > MAX_LINE_BYTES:
            raise ProtocolError(
                f"request of {len(line)} bytes: longer than MAX_LINE_BYTES = {MAX_LINE_BYTES}"
                " (send a big trajectory as a file)"
            )
        try:
            line = line.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ProtocolError(f"not UTF-8 at byte {exc.start}") from exc
    try:
        obj = json.loads(line, parse_int=_bounded_int)
    except (json.JSONDecodeError, RecursionError) as exc:
        pos = getattr(exc, "pos", "?")
        raise ProtocolError(f"not JSON (at character {pos})") from exc
    if not isinstance(obj, dict):
        raise ProtocolError("a request must be a JSON object")
    extra = set(obj) - {"id", "cmd", "args"}
    if extra:
        raise ProtocolError("unknown key", field=sorted(extra)[0])
    rid = obj.get("id", 0)
    if not isinstance(rid, int) or isinstance(rid, bool):
        raise ProtocolError("must be an integer", field="id")
    cmd = obj.get("cmd")
    if not isinstance(cmd, str):
        raise ProtocolError("missing or not a string", field="cmd")
    model = COMMANDS.get(cmd)
    if model is None:
        raise ProtocolError(f"unknown command {cmd!r}; known: {sorted(COMMANDS)}", field="cmd")
    raw_args = obj.get("args", {})
    if not isinstance(raw_args, dict):
        raise ProtocolError("must be an object", field="args")
    try:
        args = model.model_validate(raw_args)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        msg = err["msg"].removeprefix("Value error, ")
        raise ProtocolError(msg, field=_field(("args", *err["loc"]))) from exc
    return Request(id=rid, cmd=cmd, args=args)


def stop_socket_path(control_path: str | Path) -> Path:
    """The daemon's stop socket beside its control socket (:mod:`cdcr_ctl.daemon.stopline`):
    ``control.sock`` -> ``control-stop.sock``."""
    p = Path(control_path)
    return p.with_name(f"{p.stem}-stop{p.suffix}")


def encode_request(cmd: str, args: dict[str, Any] | None = None, rid: int = 0) -> bytes:
    """One request line, validated first so a client never sends what the daemon would refuse."""
    line = json.dumps({"id": rid, "cmd": cmd, "args": args or {}}, allow_nan=False)
    if len(line) >= MAX_LINE_BYTES:
        raise ProtocolError(
            f"request of {len(line)} bytes: longer than MAX_LINE_BYTES = {MAX_LINE_BYTES}"
            " (send a big trajectory as a file)"
        )
    parse_request(line)
    return line.encode() + b"\n"


def _clean(value: Any) -> Any:
    """Make a result JSON-safe: NaN/inf become null (JSON has no NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_clean(v) for v in value]
    return value


def encode_reply(rid: int, result: Any = None, error: RigError | str | None = None) -> bytes:
    if error is None:
        body: dict[str, Any] = {"id": rid, "ok": True, "result": _clean(result)}
    else:
        body = {"id": rid, "ok": False, "error": str(error)}
        if isinstance(error, ProtocolError) and error.field:
            body["field"] = error.field
    return json.dumps(body, allow_nan=False).encode() + b"\n"
