"""The vertebra design as the control loop's ``RobotModelPort`` (fuel-tank vertebra robot paper).

:class:`VertebraModel`: the kinematic cable displacements of eq. 5 (mode ``off``), plus the statics
sag (``model``), plus the attitude loop on the joint angles decoded from the sensors (eq. 6-8,
:class:`AttitudeLoopParams`), with its offset ramped at a bounded rate.

Units: mm (pulled in), rad, s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.vertebra.attitude import decode_joint_attitudes
from cdcr_ctl.model.vertebra.cables import _path_lengths_x, cable_displacements, x_from_psi
from cdcr_ctl.model.vertebra.forward import _psi_array, tip_position
from cdcr_ctl.model.vertebra.params import SINGULAR_TOL, VertebraArm
from cdcr_ctl.model.vertebra.statics import statics_x

# =========================================================================== loop adapter
#: Default integral gain of the attitude loop (1/s): bending-vector correction per second per
#: rad of error. Sensor at 100 Hz with ~10-30 ms delay: 5/s keeps > 60 deg of phase margin.
ATTITUDE_GAIN_PER_S = 5.0
#: Largest attitude correction of one joint's bending vector (rad): a wrong sensor cannot drive
#: the arm far (anti-windup).
ATTITUDE_MAX_CORRECTION_RAD = 0.3
#: A joint whose decode observability is below this is not corrected (gravity nearly along its
#: bend axis: the tilt does not show the bend).
ATTITUDE_MIN_OBSERVABILITY = 0.2
#: The error the integral sees is saturated at this (rad per joint): the correction then moves
#: at most gain * this rad/s (5/s * 0.02 = 0.1 rad/s, ~1.5 mm/s of cable at r = 15 mm), so a
#: decode jump or a large transient error cannot push the cables past their speed limit.
ATTITUDE_MAX_ERROR_RAD = 0.02


@dataclass(frozen=True)
class AttitudeLoopParams:
    """The joint-space closed loop on the attitude sensors (mode ``measured``).

    ``gain_per_tick``: integral gain per control cycle (gain per s times the period);
    ``max_correction_rad``, ``min_observability``, ``max_error_rad``: see the constants;
    ``stale_after_s``: older readings are not used (the correction is held); ``base_up``,
    ``mounts``, ``singular_tol``: :func:`decode_joint_attitudes`.

    ``max_offset_step_mm``: applies to modes ``model`` AND ``measured``: the largest change per
    control cycle of the compensation offset q_cmd - q_nominal of each cable (mm; the
    compensation's rate limit in mm/s times the period, ``vertebra.compensation_max_rate_mm_s``).
    The planned motion uses a share of each axis' speed limit; the offset adds its rate on top,
    so bounding it keeps the sum within the limit. Infinite: no bound.
    """

    gain_per_tick: float = ATTITUDE_GAIN_PER_S / 100.0
    max_correction_rad: float = ATTITUDE_MAX_CORRECTION_RAD
    min_observability: float = ATTITUDE_MIN_OBSERVABILITY
    max_error_rad: float = ATTITUDE_MAX_ERROR_RAD
    stale_after_s: float = 0.1
    base_up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    mounts: tuple[np.ndarray, ...] | None = None
    singular_tol: float = SINGULAR_TOL
    max_offset_step_mm: float = math.inf

    def __post_init__(self) -> None:
        if not (0.0 < self.gain_per_tick <= 1.0 and self.max_correction_rad > 0):
            raise ModelError("attitude loop: 0 < gain_per_tick <= 1 and max_correction_rad > 0")
        if not self.max_offset_step_mm > 0:
            raise ModelError("compensation: max_offset_step_mm must be > 0")


@dataclass
class VertebraLoopState:
    """Memory of :class:`VertebraModel` between cycles: the statics offset (warm start, x_kin -
    x_target) and the sag at the last x_kin (the statics' warm start), the attitude loop's
    integral correction (N, 2 bending vectors), the last decoded directions (continuity through
    singular poses), the last measured joint poses and the cable offset q_cmd - q_nominal last
    commanded (mm, rate-limited; None: zero, as in mode off)."""

    sag_offset: np.ndarray | None = None
    sag: np.ndarray | None = None
    offset_mm: np.ndarray | None = None
    correction: np.ndarray | None = None
    prev_phi: np.ndarray | None = None
    measured_psi: np.ndarray | None = None
    updates: int = 0


class VertebraModel:
    """The vertebra design as the control loop's ``RobotModelPort``: psi rows (theta, phi) per
    joint (rad); mm pulled in, cable order.

    Modes: ``off`` the paper's kinematic control (eq. 5); ``model`` adds the statics sag
    compensation (:func:`statics_inverse_x`, warm-started: one statics evaluation per cycle);
    ``measured`` closes a joint-space loop on the attitude sensors: each cycle the joints' poses
    are decoded from the sensors (eq. 6-8, :func:`decode_joint_attitudes`) and the commanded
    bending vectors are corrected by an integral of their error,

        c <- clip(c + g (x_cmd - x_measured)),   q = eq. 5 (x_cmd + c),

    per joint while its reading is fresh and observable (else c is held). The sensors reach the
    model through :meth:`attach_attitude` (an :class:`~cdcr_ctl.control.ports.AttitudePort`:
    latest roll, pitch and age per joint, never blocking); without one, ``measured`` raises.

    In both compensating modes the cable offset q_cmd - q_nominal moves towards its target by
    at most ``attitude_loop.max_offset_step_mm`` per cycle: entering a compensating mode ramps
    the compensation in from zero (mode off commands no offset), and the offset's rate never adds
    more than that to the planned cable speed.
    """

    def __init__(self, arm: VertebraArm, attitude_loop: AttitudeLoopParams | None = None) -> None:
        self.arm = arm
        self.n_segments = arm.n_joints
        self.n_cables = arm.n_cables
        self.attitude_loop = attitude_loop or AttitudeLoopParams()
        self.attitude: object | None = None

    def attach_attitude(self, port: object | None) -> None:
        """Use ``port`` (``latest() -> (roll_rad (N,), pitch_rad (N,), age_s (N,))``) in mode
        ``measured``; None detaches."""
        self.attitude = port

    def new_state(self) -> VertebraLoopState:
        return VertebraLoopState()

    def q_nominal(self, psi: np.ndarray) -> np.ndarray:
        return cable_displacements(self.arm, psi)

    def measure(self, state: VertebraLoopState) -> tuple[np.ndarray, np.ndarray] | None:
        """Decode the attached sensors: (psi (N, 2), usable (N,) bool), or None without sensors.

        A joint is usable when its sensor and its parent's are fresh and its observability is
        at least ``min_observability``.
        """
        if self.attitude is None:
            return None
        p = self.attitude_loop
        roll, pitch, age = (np.asarray(v, dtype=float) for v in self.attitude.latest())  # type: ignore[attr-defined]
        N = self.arm.n_joints
        if roll.shape != (N,) or pitch.shape != (N,):
            raise ModelError(f"attitude port gave {roll.shape} readings for {N} joints")
        fresh = np.isfinite(roll) & np.isfinite(pitch) & (np.asarray(age) <= p.stale_after_s)
        if not fresh.any():
            return np.zeros((N, 2)), np.zeros(N, dtype=bool)
        dec = decode_joint_attitudes(
            np.where(fresh, roll, 0.0),
            np.where(fresh, pitch, 0.0),
            np.asarray(p.base_up),
            None if p.mounts is None else list(p.mounts),
            state.prev_phi,
            p.singular_tol,
        )
        psi = np.array([[d.theta, d.phi] for d in dec])
        parent_fresh = np.concatenate(([True], fresh[:-1]))
        obs = np.array([d.observability for d in dec])
        usable = fresh & parent_fresh & (obs >= p.min_observability)
        state.prev_phi = psi[:, 1].copy()
        state.measured_psi = psi
        return psi, usable

    def q_command(
        self,
        psi: np.ndarray,
        q_nominal: np.ndarray,
        state: object,
        mode: str,
        measured_N: np.ndarray | None,
    ) -> np.ndarray:
        if not isinstance(state, VertebraLoopState):
            raise ModelError("q_command needs the state made by new_state()")
        q_nom = np.asarray(q_nominal, dtype=float)
        if mode == "off":
            state.offset_mm = None
            return q_nom
        p_cmd = _psi_array(psi, self.arm.n_joints)
        x_cmd = x_from_psi(p_cmd)
        if mode == "model":
            # one fixed-point step of statics_inverse_x (statics_inverse_step), the statics
            # itself warm-started from the last cycle's sag
            guess = x_cmd if state.sag_offset is None else x_cmd + state.sag_offset
            x_sagged = statics_x(self.arm, guess, state.sag)[0]
            state.sag = x_sagged - guess
            x_kin = guess + (x_cmd - x_sagged)
            state.sag_offset = x_kin - x_cmd
            # eq. 5 at x_kin minus eq. 5 at x_cmd = L(x_cmd) - L(x_kin)
            target = _path_lengths_x(self.arm, x_cmd) - _path_lengths_x(self.arm, x_kin)
            return q_nom + self._ramp_offset(state, target)
        if mode != "measured":
            raise ModelError(
                f"the vertebra model compensates in mode off, model or measured, not {mode!r}"
            )
        got = self.measure(state)
        if got is None:
            raise ModelError("mode measured needs the attitude sensors (none attached)")
        psi_meas, usable = got
        c = np.zeros_like(x_cmd) if state.correction is None else state.correction
        err = x_cmd - x_from_psi(psi_meas)
        p = self.attitude_loop
        e_norm = np.hypot(err[:, 0], err[:, 1])
        err = err * np.minimum(1.0, p.max_error_rad / np.maximum(e_norm, 1e-300))[:, None]
        c = c + np.where(usable[:, None], p.gain_per_tick * err, 0.0)
        norm = np.hypot(c[:, 0], c[:, 1])
        c = c * np.minimum(1.0, p.max_correction_rad / np.maximum(norm, 1e-300))[:, None]
        state.correction = c
        state.updates += int(usable.any())
        target = _path_lengths_x(self.arm, x_cmd) - _path_lengths_x(self.arm, x_cmd + c)
        return q_nom + self._ramp_offset(state, target)

    def _ramp_offset(self, state: VertebraLoopState, target_mm: np.ndarray) -> np.ndarray:
        """The cable offset of this cycle: ``target_mm`` approached from the last one by at most
        ``max_offset_step_mm`` per cable (mm)."""
        prev = np.zeros_like(target_mm) if state.offset_mm is None else state.offset_mm
        step = self.attitude_loop.max_offset_step_mm
        offset = prev + np.clip(target_mm - prev, -step, step)
        state.offset_mm = offset
        return offset

    def tip(self, psi: np.ndarray) -> np.ndarray:
        return tip_position(self.arm, psi)
