"""Robots and helpers shared by the cc-disk model tests (imported as ``cc_robots``).

The Qi rig, the 3-segment example config, small synthetic robots; a central-difference Jacobian.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.config.build_model import robot_params
from cdcr_ctl.model.cc_disk.params import CableParams, PulleyParams, RobotParams, SegmentParams

ROOT = Path(__file__).resolve().parents[2]


def make_robot(
    n_segments: int = 1,
    n_disks: int = 5,
    thickness_mm: float = 0.0,
    mass_g: float = 0.8,
    mu: float = 0.26,
    EA_N: float = 2493.0,
    pulleys: tuple[PulleyParams, ...] | None = None,
    twist_rad: float = 0.3,
    pretension_step_N: float = 0.0,
) -> RobotParams:
    """S segments (90, 80, 70 mm...), 3 cables each at 120 deg, hole pattern turned per segment."""
    if pulleys is None:
        pulleys = (
            PulleyParams("pa", 8.0, 1.5708, 0.15, 0.67),
            PulleyParams("pb", 10.0, 0.7854, 0.12, 1.0),
        )
    segs = tuple(
        SegmentParams(
            f"s{i}", 90.0 - 10.0 * i, 1206.0 / (1 + 0.5 * i), n_disks, mass_g, thickness_mm
        )
        for i in range(n_segments)
    )
    cabs = tuple(
        CableParams(
            name=f"c{i}{k}",
            segment=i,
            hole_angle_rad=2.0 * math.pi * k / 3.0 + twist_rad * i,
            routing_radius_mm=4.0,
            diameter_mm=0.8,
            EA_N=EA_N,
            pretension_N=2.0 + pretension_step_N * k,
            mu_disk=mu + 0.02 * k,
            free_length_mm=150.0,
            pulleys=pulleys,
        )
        for i in range(n_segments)
        for k in range(3)
    )
    return RobotParams(segs, cabs)


@functools.cache
def qi_params() -> RobotParams:
    return robot_params(load_rig_config(ROOT / "config" / "qi2023.yaml").robot)


@functools.cache
def three_params() -> RobotParams:
    return robot_params(load_rig_config(ROOT / "config" / "three_segment_example.yaml").robot)


def central_diff(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Central finite-difference Jacobian of a vector function (columns = d/dx_j)."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x), dtype=float)
    J = np.zeros((f0.size, x.size))
    for j in range(x.size):
        e = np.zeros_like(x)
        e[j] = h
        J[:, j] = (np.asarray(f(x + e)).ravel() - np.asarray(f(x - e)).ravel()) / (2 * h)
    return J
