"""The live view: the run log's channels over the Foxglove WebSocket protocol while the rig runs.

A publisher thread samples the loop's latest cycle row ``rate_hz`` times a second and logs it on
the channels of :mod:`cdcr_ctl.runlog.streams` (same topics, schemas and JSON as ``run.mcap``),
the model tip of the command on ``/tip/model``, a latched supervisor trip on ``/events`` when it
changes, and ``scene_hz`` times a second the backbone of the commanded pose as a
``foxglove.SceneUpdate`` on ``/scene/backbone`` (frame ``base``, metres as Foxglove's 3D panel
expects). The server is the ``foxglove-sdk`` package's (Rust, its own threads), in a context of
its own so nothing else in the process logs to it.

The publisher never touches the real-time thread: it reads the row the loop already made (an
immutable object) and does all formatting itself. With no client connected the SDK drops the
messages at once.

Exposure: no authentication. The server binds ``live.host`` (127.0.0.1 unless the config names
another address) and is off unless ``live.enabled``.

Reach: the SDK's server names the Foxglove WebSocket protocol ``foxglove.sdk.v1`` (Foxglove's
stance: the protocol of ``foxglove.websocket.v1`` under a new name) and refuses in the handshake,
with HTTP 400 and the body ``Missing expected sec-websocket-protocol header``, a client that does
not offer that name; the SDK has no setting for the old one. Such a client (a viewer from before
the SDK) is told so in the daemon's log: :class:`RefusalNote` adds what to upgrade to the SDK's
own "handshake failed" line. ``docs/operating/channels.md`` lists the viewers that connect.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import foxglove
import numpy as np
from foxglove.channels import SceneUpdateChannel
from foxglove.messages import (
    Color,
    LinePrimitive,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Vector3,
)

from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.config.registry import design_of
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.model.cc_disk import kinematics
from cdcr_ctl.runlog import streams
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, phi_cmd, sample_columns, theta_cmd
from cdcr_ctl.runlog.model_tip import model_tip_message
from cdcr_ctl.runlog.streams import RowStreams, TipFromPsi

log = logging.getLogger(__name__)

#: Sub-arcs drawn per constant-curvature segment.
ARCS_PER_SEGMENT = 12
#: Frame of the 3D scene: the robot base frame.
FRAME = "base"
_MM = 1e-3  # Foxglove's 3D panel works in metres

#: The WebSocket subprotocol the SDK's server accepts, and the name older clients offer.
SUBPROTOCOL = "foxglove.sdk.v1"
OLD_SUBPROTOCOL = "foxglove.websocket.v1"
#: The SDK's logger of refused handshakes.
SDK_SERVER_LOGGER = "foxglove.websocket.server"
UPGRADE_HINT = (
    f"the live view speaks the Foxglove WebSocket protocol as {SUBPROTOCOL}; a client offering"
    f" only {OLD_SUBPROTOCOL} is refused (HTTP 400): use the Foxglove app or Lichtblick 1.22.0 or"
    f" later, or make the client offer {SUBPROTOCOL} (docs/operating/channels.md)"
)

RowSource = Callable[[], Mapping[str, Any] | None]
TripSource = Callable[[], Any]
Backbone = Callable[[np.ndarray], np.ndarray]


def cc_backbone(lengths_mm: Sequence[float], arcs: int = ARCS_PER_SEGMENT) -> Backbone:
    """Backbone points (mm, base frame), shape (1 + S * arcs, 3), of a constant-curvature robot
    for commanded (θ, φ) per segment, shape (S, 2), rad (Qi et al. 2023 eq. 1-3).

    A constant-curvature arc of bend θ and length L split into ``arcs`` equal pieces is a chain of
    arcs of bend θ/arcs, length L/arcs in the same bending plane φ, so the chain of eq. 3 over the
    pieces gives points on the arc exactly."""
    lengths = np.repeat(np.asarray(lengths_mm, dtype=float) / arcs, arcs)

    def points(psi: np.ndarray) -> np.ndarray:
        psi = np.asarray(psi, dtype=float).reshape(-1, 2)
        sub = np.repeat(psi, arcs, axis=0)
        sub[:, 0] /= arcs
        return np.vstack([np.zeros(3)] + [p for _, p in kinematics.chain(sub, lengths)])

    return points


def tip_line(tip_from_psi: TipFromPsi) -> Backbone:
    """Base and model tip (mm) for designs without a constant-curvature backbone."""

    def points(psi: np.ndarray) -> np.ndarray:
        return np.vstack([np.zeros(3), np.asarray(tip_from_psi(psi), dtype=float).reshape(3)])

    return points


def scene_of(points_mm: np.ndarray, tracked_mm: Sequence[float | None] | None) -> SceneUpdate:
    """The backbone as a line strip (metres, frame ``base``) and the tracked tip as a sphere."""
    pts = [Point3(x=x * _MM, y=y * _MM, z=z * _MM) for x, y, z in np.asarray(points_mm)]
    ident = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(w=1.0))
    entities = [
        SceneEntity(
            frame_id=FRAME,
            id="backbone",
            lines=[
                LinePrimitive(
                    pose=ident,
                    thickness=0.004,
                    points=pts,
                    color=Color(r=0.2, g=0.6, b=1.0, a=1.0),
                )
            ],
        )
    ]
    if tracked_mm is not None and all(v is not None and math.isfinite(v) for v in tracked_mm):
        x, y, z = (float(v) * _MM for v in tracked_mm)  # type: ignore[arg-type]
        entities.append(
            SceneEntity(
                frame_id=FRAME,
                id="tracked_tip",
                spheres=[
                    SpherePrimitive(
                        pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(w=1.0)),
                        size=Vector3(x=0.004, y=0.004, z=0.004),
                        color=Color(r=1.0, g=0.3, b=0.2, a=1.0),
                    )
                ],
            )
        )
    return SceneUpdate(entities=entities)


class RefusalNote(logging.Filter):
    """Adds :data:`UPGRADE_HINT` to the SDK's "handshake failed" log line (a client that did not
    offer :data:`SUBPROTOCOL`, most often an older viewer, or no WebSocket client at all)."""

    def filter(self, record: logging.LogRecord) -> bool:
        msg = record.getMessage()
        if "handshake failed" in msg and UPGRADE_HINT not in msg:
            record.msg, record.args = f"{msg} ({UPGRADE_HINT})", ()
        return True


def _note_refusals() -> None:
    sdk_log = logging.getLogger(SDK_SERVER_LOGGER)
    if not any(isinstance(f, RefusalNote) for f in sdk_log.filters):
        sdk_log.addFilter(RefusalNote())


class LiveView:
    """The live server and its publisher thread. ``start()`` / ``stop()``; a context manager.

    ``latest_row()`` returns the loop's latest cycle row (a mapping of run-log columns) or None;
    ``columns`` are the run log's columns; ``tip_from_psi`` the model tip (mm) of a commanded pose
    (S, 2) rad; ``backbone`` its backbone points (mm); ``latest_trip()`` the latched trip (an
    object with ``cause`` and ``detail``) or None. Raises :class:`OSError` naming the address if
    the server cannot listen.
    """

    def __init__(
        self,
        latest_row: RowSource,
        columns: Sequence[str],
        *,
        host: str = "127.0.0.1",
        port: int = 8765,
        rate_hz: float = 50.0,
        scene_hz: float = 10.0,
        tip_from_psi: TipFromPsi | None = None,
        backbone: Backbone | None = None,
        latest_trip: TripSource | None = None,
        name: str = "cdcr-ctl",
    ) -> None:
        self.latest_row, self.latest_trip = latest_row, latest_trip
        self.rows = RowStreams(tuple(columns))
        self.host, self.port = host, int(port)
        self.period_s = 1.0 / rate_hz
        self.scene_every = max(1, round(rate_hz / scene_hz))
        self.tip_from_psi, self.backbone = tip_from_psi, backbone
        self.name = name
        self.published = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server: Any = None
        self._ctx: Any = None

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def start(self) -> LiveView:
        _note_refusals()
        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=self.name, host=self.host, port=self.port, context=self._ctx
            )
        except Exception as exc:  # the SDK raises its own error type for a bind failure
            raise OSError(f"live view: cannot listen on {self.url}: {exc}") from exc
        self.port = self._server.port
        self._channels = {
            topic: foxglove.Channel(
                topic, schema=self._schema(topic), message_encoding="json", context=self._ctx
            )
            for topic in streams.SCHEMAS
            if topic != streams.CAN  # raw CAN stays in the file: 8 kHz of frames is no view
        }
        self._scene = SceneUpdateChannel(streams.SCENE, context=self._ctx)
        self._thread = threading.Thread(target=self._run, name="live-view", daemon=True)
        self._thread.start()
        log.info("live view on %s", self.url)
        return self

    @staticmethod
    def _schema(topic: str) -> foxglove.Schema:
        name, _ = streams.SCHEMAS[topic]
        return foxglove.Schema(name=name, encoding="jsonschema", data=streams.schema_bytes(topic))

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self._server is not None:
            self._server.stop()
            self._server = None

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ publisher thread
    def _run(self) -> None:
        last_cycle: Any = None
        last_trip: Any = None
        tick = 0
        next_t = time.monotonic()
        while not self._stop.is_set():
            next_t += self.period_s
            try:
                last_cycle = self._publish(last_cycle, tick)
                last_trip = self._publish_trip(last_trip)
            except Exception:  # a bad row must not end the view
                log.exception("live view: publishing failed")
            tick += 1
            delay = next_t - time.monotonic()
            if delay < 0:  # fell behind (a loaded machine): skip, never burst
                next_t = time.monotonic()
                delay = 0.0
            self._stop.wait(delay)

    def _publish(self, last_cycle: Any, tick: int) -> Any:
        row = self.latest_row()
        if row is None or len(row) == 0:
            return last_cycle
        d = self.rows.as_dict(row)
        cycle = d.get("cycle")
        if cycle is not None and cycle == last_cycle:
            return last_cycle  # the loop has not moved on (stopped): nothing new
        now = time.time_ns()
        n = int(cycle) if cycle is not None else tick
        for topic, msg in self.rows.messages(d, n):
            self._channels[topic].log(msg, log_time=now)
            self.published += 1
        S = self.rows.counts[0]
        if self.tip_from_psi is not None and S:
            tip = model_tip_message(d, n, S, self.tip_from_psi)
            if tip is not None:
                self._channels[streams.TIP_MODEL].log(tip, log_time=now)
        if self.backbone is not None and S and tick % self.scene_every == 0:
            psi = np.array([[d.get(theta_cmd(i)), d.get(phi_cmd(i))] for i in range(1, S + 1)])
            psi = psi.astype(float)
            if np.isfinite(psi).all():
                tracked = [d.get("tip_x_mm"), d.get("tip_y_mm"), d.get("tip_z_mm")]
                self._scene.log(scene_of(self.backbone(psi), tracked), log_time=now)
        return cycle

    def _publish_trip(self, last: Any) -> Any:
        if self.latest_trip is None:
            return last
        trip = self.latest_trip()
        if trip is not None and trip is not last:
            msg = {
                "t_s": float(getattr(trip, "t_s", math.nan)),
                "cycle": -1,
                "event": f"{getattr(trip, 'cause', trip)}: {getattr(trip, 'detail', '')}",
            }
            if not math.isfinite(msg["t_s"]):
                msg["t_s"] = None
            self._channels[streams.EVENTS].log(msg, log_time=time.time_ns())
        return trip


def live_view_for(
    cfg: RigConfig,
    latest_row: RowSource,
    latest_trip: TripSource | None = None,
    source: str = "",
) -> LiveView:
    """The live view of a rig config's ``live`` section (not started). The scene draws the
    constant-curvature backbone for ``cc_disk`` rigs, the line base - model tip otherwise.

    The model tip comes from a model instance of its own (built here from ``cfg``; ``source``
    names the file in errors): the publisher thread never shares the loop's model object."""
    tip_from_psi = build_model(cfg, source=source).tip
    live = cfg.live
    S, K = len(cfg.robot.segments), len(cfg.robot.cables)
    draw = {  # how the design's registry entry says its arm is drawn
        "cc": lambda: cc_backbone([s.length_mm for s in cfg.robot.segments]),
        "tip_line": lambda: tip_line(tip_from_psi),
    }
    backbone: Backbone = draw[design_of(cfg.design).backbone]()
    return LiveView(
        latest_row,
        sample_columns(S, K, LOOP_EXTRA_COLUMNS),
        host=live.host,
        port=live.port,
        rate_hz=live.rate_hz,
        scene_hz=live.scene_hz,
        tip_from_psi=tip_from_psi,
        backbone=backbone,
        latest_trip=latest_trip,
        name=f"cdcr-ctl {cfg.name}",
    )
