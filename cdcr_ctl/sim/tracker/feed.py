"""The world feed of the simulated trackers: the truth pose, the true alignment, noise.

The truth callable takes no argument and returns the pose now, either as ``(R, p_mm)`` (a 3x3
rotation and a position in mm) or as a bare position ``p_mm`` (rotation = identity):

- ``truth_frame="base"``: the TIP pose in the robot base frame (what the robot model computes);
  the simulator inverts the tracker transform (``transform``: the *true* alignment, which may
  differ from the controller's config to simulate a calibration error) to get the rigid body's
  pose in the tracker frame;
- ``truth_frame="tracker"``: the rigid BODY pose in the tracker frame (mm).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np

from cdcr_ctl.config.tracking import RigidTransformConfig, TrackerConfig
from cdcr_ctl.sensors.tracker import TrackerTransform, rotation_from_rotvec

Pose = tuple[np.ndarray, np.ndarray]
Truth = Callable[[], Pose | np.ndarray]


class TruthSampler:
    """Turns the truth callable into a noisy rigid-body pose in tracker frame and units.

    ``noise_mm``: standard deviation of isotropic Gaussian position noise (mm). ``rng``: numpy
    Generator (seeded by the caller for repeatable runs).
    """

    def __init__(
        self,
        truth: Truth,
        transform: TrackerTransform,
        truth_frame: Literal["base", "tracker"],
        noise_mm: float,
        rng: np.random.Generator,
    ) -> None:
        if truth_frame not in ("base", "tracker"):
            raise ValueError(f"truth_frame must be 'base' or 'tracker', not {truth_frame!r}")
        self.truth = truth
        self.transform = transform
        self.truth_frame = truth_frame
        self.noise_mm = float(noise_mm)
        self.rng = rng

    def sample(self) -> tuple[np.ndarray, np.ndarray]:
        """(body position in tracker units, R_tracker_body) now as arrays: :meth:`sample_floats`."""
        p, rows = self.sample_floats()
        return np.array(p), np.array(rows)

    def sample_floats(self) -> tuple[list[float], list[list[float]]]:
        """(body position in tracker units, R_tracker_body's three rows) now, as Python floats:
        the truth pose through the true alignment, plus Gaussian noise of ``noise_mm`` per
        coordinate (divided by the tracker's mm per unit)."""
        got = self.truth()
        if isinstance(got, tuple):
            R, p_mm = np.asarray(got[0], dtype=float), np.asarray(got[1], dtype=float)
        else:
            R, p_mm = np.eye(3), np.asarray(got, dtype=float)
        mpu = self.transform.mm_per_unit
        if self.truth_frame == "base":
            p_units, rows = self.transform.body_in_tracker_floats(p_mm, R)
        else:
            p_units, rows = (p_mm / mpu).tolist(), R.tolist()
        if self.noise_mm > 0:
            noise = self.rng.normal(0.0, self.noise_mm, 3).tolist()
            p_units = [a + n / mpu for a, n in zip(p_units, noise, strict=True)]
        return p_units, rows


def true_transform(
    tracker: TrackerConfig, offset: RigidTransformConfig | None = None
) -> TrackerTransform:
    """The world's tracker alignment: the controller's ``base_from_tracker`` followed by
    ``offset`` (a rigid error applied in the base frame: ``p_true = R_o p_cfg + t_o``)."""
    cfg = TrackerTransform.from_config(tracker)
    if offset is None:
        return cfg
    R_o = rotation_from_rotvec(offset.rotvec_rad)
    t_o = np.asarray(offset.translation_mm, dtype=float)
    return TrackerTransform(
        R_o @ cfg.R_base_tracker,
        R_o @ cfg.t_base_tracker_mm + t_o,
        cfg.R_body_tip,
        cfg.t_body_tip_mm,
        cfg.mm_per_unit,
    )
