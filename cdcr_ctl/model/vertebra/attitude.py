"""Joint angles of the vertebra arm from attitude sensors (fuel-tank vertebra robot paper, eq. 6-8).

The sensor's ZYX orientation eq. 6 (:func:`rotation_zyx`), a joint's own (theta, phi) from the
relative rotation of its end to its base, eq. 7-8 (:func:`angles_from_relative_rotation`),
generalised to yaw-free tilt pairs (:func:`angles_from_tilts`), and the decode of every joint
from the sensors (:func:`decode_joint_attitudes`, :func:`decode_from_rotations`).

Units: rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.model.vertebra.forward import rot_x, rot_y, rot_z
from cdcr_ctl.model.vertebra.params import SINGULAR_TOL


# =========================================================================== eq. 6-8
def rotation_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Eq. 6: R = Rz(yaw) Ry(pitch) Rx(roll), the attitude sensor's Z-Y-X Euler convention.

    The printed matrix of eq. 6 is this product (its text says "Z-Y-Z" for the joint model and
    "Z-Y-X" for the sensor; the matrix is Z-Y-X with alpha = yaw, beta = pitch, gamma = roll).
    R maps sensor coordinates to world coordinates (world z up).
    """
    return rot_z(yaw_rad) @ rot_y(pitch_rad) @ rot_x(roll_rad)


def world_up_in_sensor(roll_rad: float, pitch_rad: float) -> np.ndarray:
    """The world z axis in sensor coordinates, R^T e_z = third row of eq. 6:
    (-sin pitch, cos pitch sin roll, cos pitch cos roll). Independent of yaw."""
    cp = math.cos(pitch_rad)
    return np.array([-math.sin(pitch_rad), cp * math.sin(roll_rad), cp * math.cos(roll_rad)])


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _nearest_mod_pi(phi0: float, prev: float) -> float:
    """phi0 or phi0 + pi, whichever is closer (on the circle) to ``prev``; wrapped to (-pi, pi]."""
    a, b = _wrap(phi0), _wrap(phi0 + math.pi)
    return a if abs(_wrap(a - prev)) <= abs(_wrap(b - prev)) else b


def angles_from_relative_rotation(
    R_rel: np.ndarray, prev_phi: float = 0.0, tol: float = SINGULAR_TOL
) -> tuple[float, float]:
    """(theta, phi) of a joint from its relative rotation R_rel = R_{i-1}^T R_i, eq. 7-8.

    Third row (a31, a32, a33) = (-s theta c phi, -s theta s phi, c theta):
    theta = atan2(sqrt(a31^2 + a32^2), a33) in [0, pi]; phi = -atan2(a32, -a31) = atan2(-a32, -a31)
    while sqrt(a31^2 + a32^2) > ``tol``. Singular cases (eq. 7-8's 0 deg / 180 deg branches):
    theta = 0: phi is undefined, ``prev_phi`` is kept (the paper's 0 when prev_phi = 0);
    theta = pi: R = 2 k k^T - I with k = (-s phi, c phi, 0), so the xy block gives
    cos 2phi = (a22 - a11)/2, sin 2phi = -(a12 + a21)/2: phi is known modulo pi (phi and phi + pi
    are the same rotation) and the one nearest ``prev_phi`` is returned.
    """
    R = np.asarray(R_rel, dtype=float)
    a31, a32, a33 = R[2, 0], R[2, 1], R[2, 2]
    s = math.hypot(a31, a32)
    theta = math.atan2(s, a33)
    if s > tol:
        return theta, math.atan2(-a32, -a31)
    if a33 > 0.0:
        return 0.0, prev_phi
    phi0 = 0.5 * math.atan2(-(R[0, 1] + R[1, 0]), R[1, 1] - R[0, 0])
    return math.pi, _nearest_mod_pi(phi0, prev_phi)


@dataclass(frozen=True)
class JointAttitude:
    """A decoded joint: bend ``theta`` [0, pi], direction ``phi`` (rad) and ``observability``
    in [0, 1] (sine of the angle between gravity and the bend axis; 0: this bend cannot be seen
    from tilt; near 0 the decode is noise-sensitive)."""

    theta: float
    phi: float
    observability: float


def angles_from_tilts(
    up_parent: np.ndarray, up_child: np.ndarray, prev_phi: float = 0.0, tol: float = SINGULAR_TOL
) -> JointAttitude:
    """A joint's (theta, phi) from the world-up vector seen by the sensors at both of its ends.

    Yaw-free decode (the magnetometer heading is not used). b = world up in the parent frame,
    a = world up in the child frame; the joint rotation R = Rot(k, theta), k = (-s phi, c phi, 0)
    (eq. 1), maps child to parent coordinates, so R a = b. A rotation about k keeps the component
    along k, so k is perpendicular to a - b and (twist-free) to z:

        k = +-(z x (a - b)) / |.|,  theta = signed angle from a_perp to b_perp about k,

    with k's sign chosen so that theta >= 0; phi = atan2(-k_x, k_y). For joint 1, b is the base's
    up vector (e.g. (0, 0, 1) for an upright base); it generalises eq. 7-8, which is this decode
    with b = e_z: then theta = atan2(sqrt(a31^2 + a32^2), a33), phi = atan2(-a32, -a31).

    Singular cases: |a - b| <= ``tol``: theta = 0 (or a bend about an axis parallel to gravity,
    which tilt cannot see; ``observability`` says which), phi = ``prev_phi``. (a - b) parallel to
    z but not 0 (e.g. theta = pi under an upright parent): every horizontal axis fits; the one at
    ``prev_phi`` is used.
    """
    b = np.asarray(up_parent, dtype=float)
    a = np.asarray(up_child, dtype=float)
    b = b / np.linalg.norm(b)
    a = a / np.linalg.norm(a)
    e = a - b
    exy = math.hypot(e[0], e[1])
    if float(np.linalg.norm(e)) <= tol:
        # straight, or bent about a horizontal axis parallel to a: the worst case over all
        # horizontal axes k of |a - (k.a) k| is |a_z|
        return JointAttitude(0.0, prev_phi, abs(float(a[2])))
    if exy > tol:
        k = np.array([-e[1], e[0], 0.0]) / exy
    else:  # every horizontal axis fits: keep the previous direction
        k = np.array([-math.sin(prev_phi), math.cos(prev_phi), 0.0])
    a_p = a - (k @ a) * k
    b_p = b - (k @ b) * k
    obs = float(np.linalg.norm(a_p))
    theta = math.atan2(float(k @ np.cross(a_p, b_p)), float(a_p @ b_p))
    if exy <= tol:
        # k fixed at prev_phi: a negative theta is the opposite direction, except at theta = pi
        # where rotations about k and -k coincide
        if theta < 0.0 and math.pi + theta > tol:
            return JointAttitude(-theta, _wrap(prev_phi + math.pi), obs)
        return JointAttitude(abs(theta), prev_phi, obs)
    if theta < 0.0:
        k, theta = -k, -theta
    return JointAttitude(theta, math.atan2(-k[0], k[1]), obs)


def rotvec_matrix(rotvec_rad: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrix of a rotation vector (axis * angle, rad)."""
    w = np.asarray(rotvec_rad, dtype=float)
    t = float(np.linalg.norm(w))
    if t < 1e-12:
        return np.eye(3)
    k = w / t
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(t) * K + (1.0 - math.cos(t)) * (K @ K)


def decode_joint_attitudes(
    roll_rad: np.ndarray,
    pitch_rad: np.ndarray,
    base_up: np.ndarray = (0.0, 0.0, 1.0),
    mounts: list[np.ndarray] | None = None,
    prev_phi: np.ndarray | None = None,
    tol: float = SINGULAR_TOL,
) -> list[JointAttitude]:
    """Every joint's (theta, phi) from the roll and pitch of the sensor on each joint end.

    Yaw is not an input: only the world-up vector R_i^T e_z of each sensor is used
    (:func:`world_up_in_sensor`), turned into the joint-end frame by the sensor's ``mounts``
    rotation (3x3, maps sensor coordinates to joint-end coordinates; None: axes parallel as in
    the paper), then
    :func:`angles_from_tilts` per joint with the previous joint end (the base's ``base_up``, the
    world up vector in the robot base frame, for joint 1). ``prev_phi`` keeps phi continuous
    through the singular poses.
    """
    rolls = np.asarray(roll_rad, dtype=float)
    pitches = np.asarray(pitch_rad, dtype=float)
    N = rolls.size
    ups = []
    for i in range(N):
        u = world_up_in_sensor(float(rolls[i]), float(pitches[i]))
        if mounts is not None:
            u = np.asarray(mounts[i], dtype=float) @ u
        ups.append(u)
    out = []
    parent = np.asarray(base_up, dtype=float)
    for i in range(N):
        prev = 0.0 if prev_phi is None else float(prev_phi[i])
        out.append(angles_from_tilts(parent, ups[i], prev, tol))
        parent = ups[i]
    return out


def decode_from_rotations(
    R_abs: list[np.ndarray],
    R_base: np.ndarray | None = None,
    prev_phi: np.ndarray | None = None,
    tol: float = SINGULAR_TOL,
) -> np.ndarray:
    """(N, 2) joint (theta, phi) from full absolute orientations (sensor -> world, eq. 6), eq. 7-8
    on R_rel = R_{i-1}^T R_i (R_0 = ``R_base``, identity when None). Use when the headings are
    trustworthy and shared (a tracker, a simulation); otherwise :func:`decode_joint_attitudes`.
    """
    parent = np.eye(3) if R_base is None else np.asarray(R_base, dtype=float)
    out = np.zeros((len(R_abs), 2))
    for i, R in enumerate(R_abs):
        Ri = np.asarray(R, dtype=float)
        prev = 0.0 if prev_phi is None else float(prev_phi[i])
        out[i] = angles_from_relative_rotation(parent.T @ Ri, prev, tol)
        parent = Ri
    return out
