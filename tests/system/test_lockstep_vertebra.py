"""System: the vertebra arm's sensors on the lock-step rig (cdcr_ctl.sim.lockstep): the attitude
sensors' WitMotion frames and the network joystick's input_event records go through the
production parsers on simulated time (the daemon-level runs are test_demo_vertebra and
test_joystick_session)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from cdcr_ctl.cli.demo import ROOT_CONFIG, make_session
from cdcr_ctl.config import load_rig_config
from cdcr_ctl.model import vertebra as vt
from cdcr_ctl.sensors.attitude import rpy_from_rotation
from cdcr_ctl.sim.lockstep.rig import PRIME_S, LockstepRig
from cdcr_ctl.sim.rig import stick_script
from cdcr_ctl.sim.simconfig import load_sim_config

TRUTH = ROOT_CONFIG / "sim" / "vertebra-truth.yaml"
#: The angle frame's resolution: 180 deg / 32768 per count (WitMotion protocol), as rad.
ANGLE_LSB_RAD = math.radians(180.0 / 32768.0)
#: The simulated sender hangs up this long after the connection (s): after the paper session's
#: first steer, its release and the first forward press and release.
CUT_S = 5.0


def _open(tmp_path, **joystick):
    runs = tmp_path / "runs"
    runs.mkdir()
    rig_path, sim_path = make_session(TRUTH, tmp_path, runs)
    if joystick:
        doc = yaml.safe_load(sim_path.read_text())
        doc["joystick"] = {"script": "paper", "scale": 0.5, **joystick}
        sim_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    loaded = load_sim_config(sim_path)
    ctl = load_rig_config(rig_path)
    return loaded, ctl, LockstepRig.open(loaded, ctl, str(rig_path), truth_process=False)


@pytest.mark.multicore
@pytest.mark.timeout(120)
def test_attitude_frames_reach_the_reader_with_the_truths_angles_on_simulated_time(tmp_path):
    loaded, _ctl, rig = _open(tmp_path)
    with rig:
        sim = loaded.sim.attitude
        sched, sensors = rig.attitude_schedule, rig.attitude.sensors
        assert sched is not None and len(sensors.sensors) == 3
        # A bent world (all three joints), then 0.2 s of simulated time for the sensors.
        psi = np.array([[0.10, 0.3], [0.20, 0.5], [0.15, -0.4]])
        q_mm = vt.cable_displacements(rig.truth.arm, psi)
        rig.truth.step(np.round(q_mm * rig.truth.counts_per_mm).astype(int).tolist())
        t, reports0 = PRIME_S, sched.reports
        for _ in range(50):
            sched.advance(t, t + 0.004)
            t += 0.004
        # rate_hz frames per sensor, the first ones latency_s after they were sampled.
        per_sensor = (sched.reports - reports0) / 3
        assert abs(per_sensor - 0.2 * sim.rate_hz) <= 1, per_sensor
        # Noise: 5 standard deviations plus one count of the angle frame.
        tol = 5 * math.radians(sim.noise_deg) + ANGLE_LSB_RAD
        for i, s in enumerate(sensors.latest(t)):
            roll, pitch, _yaw = rpy_from_rotation(rig.truth.sensor_orientation(i))
            assert not s.stale and s.age_s <= sim.latency_s + 1.0 / sim.rate_hz + 1e-9, s
            assert abs(s.roll_rad - roll) <= tol and abs(s.pitch_rad - pitch) <= tol, (i, s)
            assert abs(roll) + abs(pitch) > 0.05  # the joints are really bent


@pytest.mark.multicore
@pytest.mark.timeout(120)
def test_joystick_script_is_played_on_simulated_time_and_the_unplug_fails_the_reader(tmp_path):
    loaded, ctl, rig = _open(tmp_path, disconnect_after_s=CUT_S)
    with rig:
        js = ctl.sensors.joystick
        stick = rig.open_joystick(js)
        t0 = rig.clock.now()
        frames = stick_script(loaded)  # the operator's intent, times from the connection
        times = sorted({f.t_s for f in frames})
        # Normalised axes: within the configured deadband of the intent (and a raw count).
        tol = js.deadband + 2.0 / 65535.0
        t, checked = t0, 0
        for k, tk in enumerate(times):
            before = t0 + tk - 1e-6
            if before > t:
                rig.joystick.advance(t, before)
                t = before
            if k > 0:  # nothing of keyframe k yet: the state of keyframe k - 1
                prev = [f for f in frames if f.t_s == times[k - 1]][-1]
                st = stick.latest(t)
                assert abs(st.x - prev.x) <= tol and abs(st.y - prev.y) <= tol, (tk, st, prev)
            rig.joystick.advance(t, t0 + tk)
            t = t0 + tk
            if tk >= CUT_S:
                break
            want = [f for f in frames if f.t_s == tk][-1]
            st = stick.latest(t)
            assert st.connected and stick.failure is None
            assert abs(st.x - want.x) <= tol and abs(st.y - want.y) <= tol, (tk, st, want)
            assert st.buttons == frozenset(want.buttons), (tk, st, want)
            checked += 1
        assert checked == 5  # 0, 1.3, 3.1, 4.1 (forward pressed), 4.4 s
        # At disconnect_after_s the sender hangs up: the reader finds the end of the stream.
        assert stick.failure is not None and "joystick disconnected" in str(stick.failure)
        assert not stick.latest(t).connected
        stick.close()
        rig.joystick.advance(t, t + 1.0)  # a closed session is dropped, nothing raised
