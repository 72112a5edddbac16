"""The intake process: big requests and trajectory files are parsed and validated out of the
loop's process; the fast (vectorised) path gives the same trajectory as the sample-by-sample one
and a bad file's error still names its line and field."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.daemon import intake as intake_mod
from cdcr_ctl.daemon.intake import Intake
from cdcr_ctl.errors import ConfigError, RigError


@pytest.fixture(scope="module")
def intake():
    it = Intake(n_segments=1, bend_rad=1.75).start()
    yield it
    it.close()


def _csv(path, rows):
    t = np.arange(rows) * 1e-2
    theta = 0.5 * (1 - np.cos(2 * np.pi * t / t[-1])) / 2
    arr = np.column_stack((t, theta, np.full(rows, 0.3)))
    np.savetxt(path, arr, delimiter=",", header="t_s,seg1_theta_rad,seg1_phi_rad", comments="")
    return arr


def test_file_is_read_in_the_worker_and_equals_the_slow_path(intake, tmp_path):
    path = tmp_path / "t.csv"
    _csv(path, 5000)
    fast = intake.load(intake.prepare_file(str(path)), "t")
    slow = tj.load_trajectory(path, n_segments=1, bend_limit_rad=1.75)
    np.testing.assert_array_equal(fast.t_s, slow.t_s)
    np.testing.assert_array_equal(fast.psi, slow.psi)


def test_fast_path_falls_back_to_the_exact_error(intake, tmp_path):
    path = tmp_path / "bad.csv"
    arr = _csv(path, 100)
    arr[50, 1] = 3.0  # beyond limits.bend_rad
    np.savetxt(path, arr, delimiter=",", header="t_s,seg1_theta_rad,seg1_phi_rad", comments="")
    assert intake_mod._fast_csv(str(path), 1, 1.75) is None
    with pytest.raises(ConfigError) as info:
        intake.prepare_file(str(path))
    assert "line 52" in str(info.value)


def test_missing_file_is_a_rig_error(intake, tmp_path):
    with pytest.raises(RigError):
        intake.prepare_file(str(tmp_path / "nope.csv"))


def test_spooled_request_comes_back_as_a_prepared_trajectory(intake):
    samples = [[0.01 * n, 0.0005 * n, 0.0] for n in range(3000)]
    spool = intake.new_spool()
    spool.write_text(
        json.dumps({"id": 7, "cmd": "trajectory", "args": {"name": "s", "samples": samples}})
    )
    req = intake.parse_spooled(spool)
    assert req.id == 7 and req.args.samples is None and req.args.file is not None
    traj = intake.load(req.args.file, "s")
    np.testing.assert_allclose(traj.t_s, [s[0] for s in samples])
    assert not spool.exists()
