"""Daemon-level joystick sessions in-process: the real daemon (loop, supervisor, run logs, control
socket) on the vertebra rig config, with drives that follow their targets exactly (no CAN: the
drive protocol has its own tests) and the simulated network joystick on loopback streaming
``struct input_event`` records of a short stick script.

Checked: the session steers the distal joint as the stick says, the forward button makes the
proximal joints follow, ``stop`` ends it with a complete log and closes the joystick, the
``seconds`` limit ends it, a joystick disconnect holds the arm with the cause logged, and the
refusals name the config key (no joystick section, not a vertebra rig).
"""

from __future__ import annotations

import contextlib
import math
import os
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import build_model
from cdcr_ctl.control import trajectory
from cdcr_ctl.control.ports import DriveState, NoTension, NoTip
from cdcr_ctl.daemon.client import ControlClient, DaemonError
from cdcr_ctl.daemon.joystick import JOYSTICK_LOST, check_session_config
from cdcr_ctl.daemon.service import Daemon, RigIO
from cdcr_ctl.errors import ConfigError
from cdcr_ctl.runlog import load_run
from cdcr_ctl.runlog.writer.factory import RunLogFactory
from cdcr_ctl.sensors.joystick import DEFAULT_RANGE
from cdcr_ctl.sim.joystick import JoystickFrame, NetworkJoystickServer, ScriptedJoystick

CONFIG = Path(__file__).resolve().parents[2] / "config"
WAIT_S = 30.0
SOUTH = frozenset({"BTN_SOUTH"})

#: Full up for 0.6 s (the distal bend grows by 0.02 rad per 0.1 s tick), then the forward button.
SCRIPT = [
    JoystickFrame(0.0, 0.0, 1.0),
    JoystickFrame(0.6, 0.0, 0.0),
    JoystickFrame(1.2, 0.0, 0.0, SOUTH),
    JoystickFrame(1.5, 0.0, 0.0),
]


class IdealDrives:
    """A DrivePort whose drives are where they were told to be (counts), enabled on request."""

    def __init__(self, n: int) -> None:
        self.counts = [0] * n
        self.enabled = False
        self.sent = 0

    def send_cycle(self, targets_counts):
        self.counts = list(targets_counts)
        self.sent += 1

    def feedback(self):
        state = "OPERATION_ENABLED" if self.enabled else "SWITCHED_ON"
        return [DriveState(c, state, "", 0.0) for c in self.counts]

    def first_fault(self):
        return None

    def enable(self):
        self.enabled = True

    def disable(self):
        self.enabled = False

    def quick_stop(self):
        self.enabled = False

    def home(self):
        return [0] * len(self.counts)

    def reset_faults(self):
        pass

    def close(self):
        pass


def _inverted(script):
    # vertebra.yaml inverts y (forward reads negative): send what such a stick sends.
    return [JoystickFrame(f.t_s, f.x, -f.y, f.buttons) for f in script]


@contextlib.contextmanager
def daemon_with_stick(tmp_path: Path, script, disconnect: bool = False, joystick: bool = True):
    frames = _inverted(script)
    server = NetworkJoystickServer(
        lambda: ScriptedJoystick(frames, disconnect_at_end=disconnect)
    ).start()
    doc = {
        "extends": str(CONFIG / "vertebra-sim.yaml"),
        "daemon": {"socket_path": str(tmp_path / "ctl.sock")},
        "logging": {"directory": str(tmp_path / "runs")},
        "sensors": {"joystick": {"device": server.url}},
    }
    rig = tmp_path / "rig.yaml"
    rig.write_text(yaml.safe_dump(doc))
    cfg = load_rig_config(rig)
    # No tracker here (the supervisor would find it stale); the attitude ports are not opened.
    sensors = {"tracker": None, "attitude": None}
    if not joystick:
        sensors["joystick"] = None
    cfg = cfg.model_copy(update={"sensors": cfg.sensors.model_copy(update=sensors)})
    model = build_model(cfg)
    drives = IdealDrives(len(cfg.robot.cables))
    io = RigIO(drives, NoTension(len(cfg.robot.cables)), NoTip(), close=lambda: None)
    d = Daemon(cfg, rig, io, model, RunLogFactory.from_config(cfg, rig), trajectory)
    d.start()
    try:
        with ControlClient(d.cfg.daemon.socket_path) as c:
            c.call("enable")
            c.call("home")
            yield SimpleNamespace(daemon=d, client=c, server=server, drives=drives)
    finally:
        d.shutdown("test over")
        server.stop()


def _wait(pred, timeout_s: float = WAIT_S) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


def _run(c: ControlClient, run_id: str) -> dict | None:
    return next((r for r in c.call("status")["runs"] if r["id"] == run_id), None)


def test_session_steers_follows_and_stop_ends_it_with_a_complete_log(tmp_path):
    with daemon_with_stick(tmp_path, SCRIPT) as t:
        d, c = t.daemon, t.client
        res = c.call("joystick", compensation="off")
        assert res["duration_s"] is None  # inf: until stop
        assert res["device"] == t.server.url
        session = d._session
        # The planner ends its follow move: the middle joint took the distal pose.
        assert _wait(
            lambda: (
                session.source.follow.log
                and session.source.follow.log[-1].mode == "follow"
                and not session.source.follow.busy
            )
        )
        # The script's four frames arrive at 0, 0.6, 1.2 and 1.5 s of stick time; the follow move
        # can end before the last one is read (a busy machine delays the reader), so wait for it.
        assert _wait(lambda: c.call("status")["joystick"]["reports"] >= 4)
        st = c.call("status")
        js = st["joystick"]
        assert js["active"] and js["connected"] and js["reports"] >= 4
        psi = np.array(st["loop"]["psi_cmd_rad"])
        # Full deflection steers the distal bend by whole increments (a steer tick every
        # steer_period_s, 0.1 s, while no step runs). How many fall in the stick's 0.6 s hangs
        # on when the reader and the loop see the frames: 4-6 on an idle machine, 3 beside
        # another test worker. So: at least one, and a whole number of them.
        inc = session.source.follow.planner.params.theta_increment_rad
        ticks = round(psi[2, 0] / inc)
        assert ticks >= 1 and psi[2, 0] == pytest.approx(ticks * inc, abs=1e-9), (psi, inc)
        assert psi[1, 0] == pytest.approx(psi[2, 0], abs=1e-6)  # followed
        assert psi[0, 0] == pytest.approx(0.0, abs=1e-9)  # the base joint had straight to copy
        assert t.server.clients == 1
        c.call("stop", mode="halt")
        assert _wait(lambda: (_run(c, res["run"]) or {}).get("state") == "stopped")
        assert _wait(lambda: not d._session.active)
        st = c.call("status")
        assert st["enabled"] and st["fault"] is None  # halt: held, still enabled
        assert st["joystick"]["active"] is False
        assert d._session.stick.running is False  # the reader was closed with the run
    run = load_run(res["log_dir"])
    assert run.ended["outcome"] == "stopped"
    assert len(run) > 50 and not run.warnings
    q = np.column_stack([run.data[f"cable{k}_q_cmd_mm"] for k in range(1, 10)])
    v = np.abs(np.diff(q, axis=0)) / np.diff(run.t_s)[:, None]
    assert v.max() <= d.cfg.limits.cable_velocity_mm_s
    assert run.data["seg3_theta_cmd_rad"][-1] == pytest.approx(psi[2, 0], abs=1e-6)


def test_seconds_limit_completes_the_run_and_closes_the_joystick(tmp_path):
    with daemon_with_stick(tmp_path, SCRIPT) as t:
        d, c = t.daemon, t.client
        res = c.call("joystick", seconds=0.5, log=True)
        assert res["duration_s"] == 0.5
        assert _wait(lambda: (_run(c, res["run"]) or {}).get("state") == "completed")
        assert _wait(lambda: not d._session.active)
        psi0 = c.call("status")["loop"]["psi_cmd_rad"]
        time.sleep(0.3)  # the completed session's pose is held
        assert c.call("status")["loop"]["psi_cmd_rad"] == psi0
        st = c.call("status")
        assert 0.0 < psi0[2][0] <= 0.12, " ".join(f"{k}={v}" for k, v in st["joystick"].items())
        # A second session may start once the first has ended.
        res2 = c.call("joystick", seconds=0.2, log=False)
        assert _wait(lambda: (_run(c, res2["run"]) or {}).get("state") == "completed")
    assert load_run(res["log_dir"]).ended["outcome"] == "completed"


def test_disconnect_holds_the_arm_and_logs_the_cause(tmp_path):
    script = [JoystickFrame(0.0, 0.0, 1.0), JoystickFrame(0.4, 0.0, 1.0)]  # unplugged at 0.4 s
    with daemon_with_stick(tmp_path, script, disconnect=True) as t:
        d, c = t.daemon, t.client
        res = c.call("joystick")
        assert _wait(lambda: (_run(c, res["run"]) or {}).get("state") == "tripped")
        run_info = _run(c, res["run"])
        assert run_info["end_reason"].startswith(f"{JOYSTICK_LOST}: ")
        assert "joystick disconnected" in run_info["end_reason"]
        st = c.call("status")
        assert st["fault"]["cause"] == JOYSTICK_LOST and st["fault"]["reaction"] == "HALT"
        assert st["enabled"]  # held, not quick-stopped
        held = list(t.drives.counts)
        psi = st["loop"]["psi_cmd_rad"]
        time.sleep(0.3)
        assert t.drives.counts == held and c.call("status")["loop"]["psi_cmd_rad"] == psi
        assert _wait(lambda: not d._session.active)
        # Latched like a stale sensor: a new session needs reset-fault.
        with pytest.raises(DaemonError, match="reset-fault"):
            c.call("joystick")
        c.call("reset_fault", confirm=True)
    run = load_run(res["log_dir"])
    assert run.ended["outcome"] == "tripped"
    assert JOYSTICK_LOST in run.ended["reason"]
    # The trip first; a row may go on with notes ("; late: ...", "; long: ...").
    assert JOYSTICK_LOST in {str(e).split("; ")[0] for e in run.data["event"]}


def test_refusals_name_the_config_key(tmp_path):
    with daemon_with_stick(tmp_path, SCRIPT, joystick=False) as t:
        c = t.client
        with pytest.raises(DaemonError, match=r"sensors\.joystick"):
            c.call("joystick")
        assert t.server.clients == 0 and c.call("status")["run"] is None
    disk = load_rig_config(CONFIG / "qi2023-sim.yaml")
    disk = disk.model_copy(
        update={"sensors": disk.sensors.model_copy(update={"joystick": _stick_cfg()})}
    )
    with pytest.raises(ConfigError) as info:
        check_session_config(disk, "qi2023-sim.yaml")
    assert info.value.key == "design" and "vertebra" in str(info.value)


def _stick_cfg():
    from cdcr_ctl.config.tracking import JoystickConfig

    return JoystickConfig(device="tcp://127.0.0.1:9")


def test_session_refused_while_one_runs_and_when_disabled(tmp_path):
    with daemon_with_stick(tmp_path, SCRIPT) as t:
        c = t.client
        res = c.call("joystick", seconds=30.0, log=False)
        with pytest.raises(DaemonError, match="is running"):
            c.call("joystick")
        c.call("stop", mode="halt")
        assert _wait(lambda: (_run(c, res["run"]) or {}).get("state") == "stopped")
        # Not while another run moves the arm (the session plans from the commanded pose).
        traj = c.call("trajectory", name="still", samples=[[0.0] + [0.0] * 6, [5.0] + [0.0] * 6])
        with pytest.raises(DaemonError, match="'still' is in progress"):
            c.call("joystick")
        c.call("stop", mode="halt")
        assert _wait(lambda: (_run(c, traj["run"]) or {}).get("state") == "stopped")
        c.call("disable")
        with pytest.raises(DaemonError, match="disabled"):
            c.call("joystick")


def test_range_default_is_signed_16_bit():
    # The simulator and the sim rig config agree on the raw range sent over the wire.
    cfg = load_rig_config(CONFIG / "vertebra-sim.yaml").sensors.joystick
    assert cfg is not None and cfg.axis_range is not None
    assert (cfg.axis_range.min, cfg.axis_range.max) == (
        DEFAULT_RANGE.minimum,
        DEFAULT_RANGE.maximum,
    )
    assert math.isfinite(cfg.connect_timeout_s)


# -- the CLI against the in-process daemon ---------------------------------------------------


def test_cli_runs_a_timed_session_and_prints_json(tmp_path, capsys):
    import json

    from cdcr_ctl.cli.main import main

    with daemon_with_stick(tmp_path, SCRIPT) as t:
        sock = t.daemon.cfg.daemon.socket_path
        code = main(["--socket", sock, "joystick", "--seconds", "0.8", "--json"])
        out = json.loads(capsys.readouterr().out)
    assert code == 0
    assert out["state"] == "completed" and out["end_reason"] == "trajectory completed"
    assert out["device"] == t.server.url and out["steps"] >= 1
    assert 0.0 < out["distal_target_rad"][0] <= 0.12
    assert load_run(out["log_dir"]).ended["outcome"] == "completed"


def test_cli_ctrl_c_sends_stop_and_the_arm_holds(tmp_path, capsys):
    import signal
    import threading

    from cdcr_ctl.cli.main import main

    with daemon_with_stick(tmp_path, SCRIPT) as t:
        sock = t.daemon.cfg.daemon.socket_path

        def interrupt():  # Ctrl-C once the session runs (SIGINT -> KeyboardInterrupt in main)
            if _wait(lambda: t.daemon._session is not None and t.daemon._session.active):
                time.sleep(0.3)
                # A process-directed SIGINT as a terminal's Ctrl-C sends: Linux gives it to the
                # main thread (raise_signal here would target this thread, and CPython 3.11 may
                # then not flag the main thread to handle it).
                os.kill(os.getpid(), signal.SIGINT)

        # Ctrl-C is Python's KeyboardInterrupt here, whatever handler an earlier test left.
        previous = signal.signal(signal.SIGINT, signal.default_int_handler)
        threading.Thread(target=interrupt, daemon=True).start()
        try:
            code = main(["--socket", sock, "joystick"])
        finally:
            signal.signal(signal.SIGINT, previous)
        captured = capsys.readouterr()
        # The session's watcher notices the run's end within SESSION_WATCH_S and closes it.
        closed = _wait(lambda: t.client.call("status")["joystick"]["active"] is False)
        st = t.client.call("status")
    assert code == 0, captured.err
    assert "sending stop (halt)" in captured.err
    assert "state: stopped" in captured.out
    assert closed and st["enabled"] and st["fault"] is None


# -- protocol ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("args", "field"),
    [
        ({"seconds": 0}, "args.seconds"),
        ({"seconds": -1.0}, "args.seconds"),
        ({"seconds": "10"}, "args.seconds"),
        ({"seconds": 1e9}, "args.seconds"),
        ({"compensation": "sag"}, "args.compensation"),
        ({"log": "yes"}, "args.log"),
        ({"name": ""}, "args.name"),
        ({"speed": 1.0}, "args.speed"),
    ],
)
def test_joystick_request_is_validated_naming_the_field(args, field):
    import json

    from cdcr_ctl.daemon.protocol import ProtocolError, parse_request

    with pytest.raises(ProtocolError) as info:
        parse_request(json.dumps({"cmd": "joystick", "args": args}))
    assert info.value.field == field


def test_joystick_request_defaults_and_limits():
    from cdcr_ctl.daemon.protocol import ProtocolError, encode_request, parse_request

    bare = parse_request('{"cmd": "joystick"}').args
    assert (bare.seconds, bare.compensation, bare.log, bare.name) == (None, None, True, "joystick")
    req = parse_request(encode_request("joystick", {"seconds": 30, "compensation": "model"}))
    assert req.args.seconds == 30.0 and req.args.compensation == "model"
    with pytest.raises(ProtocolError) as info:
        parse_request('{"cmd": "joystick", "args": {"seconds": NaN}}')
    assert info.value.field == "args.seconds"


def test_supervisor_extra_checks_trip_latch_and_are_removed():
    from cdcr_ctl.control.supervisor import CycleCheck, Reaction, Supervisor, Trip

    limits = load_rig_config(CONFIG / "vertebra-sim.yaml").limits
    sup = Supervisor(limits)
    lost = [False]

    class Watch:
        def check(self, c):
            return Trip(JOYSTICK_LOST, Reaction.HALT, "gone", c.t_s) if lost[0] else None

    w = Watch()
    sup.add_check(w.check)
    still = CycleCheck(t_s=1.0, dt_s=0.01, q_cmd_mm=[0.0] * 9, q_prev_mm=[0.0] * 9)
    assert sup.check(still) is None and sup.trip is None
    lost[0] = True
    trip = sup.check(still)
    assert trip is not None and trip.cause == JOYSTICK_LOST and sup.trip is trip
    assert sup.cycle_worst.reaction is Reaction.HALT  # the loop holds the last command
    assert sup.check(still) is None and sup.later_trips == 1  # latched: counted, not repeated
    sup.remove_check(w.check)  # a new bound method object: removed by equality
    assert sup.extra_checks == () and sup.check(still) is None and sup.cycle_worst is None
