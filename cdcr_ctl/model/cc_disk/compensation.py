"""Drive compensation q~ = q + delta (Qi et al. 2023 eq. 37) and the control loop's model port.

Given the desired pose psi of every segment and the friction state, the chain of
:class:`~cdcr_ctl.model.cc_disk.transfer.ForceTransfer` gives: statics -> anchor tensions -> disk
friction -> base tensions -> pulley friction -> actuator tensions (and the tension at each load
cell) -> elongation delta -> q~ = q_geom + delta. With the tensions of the load cells in place of
the modelled ones (mode ``"measured"``) only the friction propagation and the elongation are
modelled, and the pretension (no-moment) mode of each segment's measured tensions is pinned by
the model's pretension rule (:meth:`Compensator.measured_transfer` says why: fed forward, it
closes a loop of gain ~1). Zero friction and rigid cables give delta = 0 exactly.

Reversals (eq. 17-19 with memory): the friction sign follows the direction in which cable
material crosses the base hole; pulling in (+1) needs more cable than paying out (-1) at one
pose, by the dead zone the truth's stuck cable makes the actuator travel. With
``reversal_band_mm`` = 0 the command crosses that dead zone in one step (the exact inverse); a
band spreads it over that much cable travel, so a reversal does not demand a velocity step.

Two ways in:

* :meth:`Compensator.compensate` - stateless: the friction state (``s`` per cable) is given.
* :meth:`Compensator.step` - stateful, for the loop: the friction state follows the direction in
  which cable material crosses the base hole (:mod:`cdcr_ctl.model.shared.friction`), with memory
  when the pose holds, so a reversal flips the friction (the inverse of the forward model's dead
  zone).

The disk friction's law is the capstan law of eq. 16-24 unless a
:class:`~cdcr_ctl.model.cc_disk.friction_law.FrictionLawShape` says otherwise: then the chain is
its :class:`~cdcr_ctl.model.cc_disk.friction_law.LawTransfer` (a wrap exponent; a speed-dependent
part follows each cable's speed |dq_geom| / ``cycle_s`` between steps, lagged by
:data:`~cdcr_ctl.model.cc_disk.friction_law.SPEED_MEMORY_S` as the discrepancy workflow's
simulation does).

:class:`CCDiskModel` adapts it to :class:`cdcr_ctl.model.port.RobotModelPort`.
Units: psi (S, 2) rows (theta, phi) in rad; q in mm pulled in; tensions in N.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from cdcr_ctl.errors import ModelError
from cdcr_ctl.model.cc_disk.friction_law import SPEED_MEMORY_S, LawTransfer
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.kinematics import tip_position_fast
from cdcr_ctl.model.cc_disk.params import Effects, Location, RobotParams
from cdcr_ctl.model.cc_disk.routing import cable_matrix_x
from cdcr_ctl.model.cc_disk.transfer import ForceTransfer, Pose, Transfer
from cdcr_ctl.model.shared.friction import FrictionState, band_update, direction_update

MODES = ("off", "model", "measured")


def psi_to_flat_x(psi: np.ndarray | Sequence[Sequence[float]]) -> list[float]:
    """(S, 2) rows (theta, phi) -> flat bending vectors [x_1, y_1, ...] (plain floats)."""
    out: list[float] = []
    # an array's rows as Python floats at once (float() of each element is the same value)
    for row in psi.tolist() if isinstance(psi, np.ndarray) else psi:
        th, ph = float(row[0]), float(row[1])
        out.append(th * math.cos(ph))
        out.append(th * math.sin(ph))
    return out


@dataclass
class CompensationState:
    """Mutable memory of :meth:`Compensator.step`: friction state and actuator-effect states."""

    s: list[float]
    w_mm: list[float]
    effect_states: list[object] = field(default_factory=list)
    last: Transfer | None = None
    #: A speed-dependent friction law's memory: the last q_geom (mm) and cable speeds (mm/s).
    q_geom_mm: list[float] | None = None
    speed_mm_s: list[float] | None = None

    def friction(self) -> FrictionState:
        return FrictionState(s=tuple(self.s), w_mm=tuple(self.w_mm))


class Compensator:
    """Inverse force-transfer model with compensation (eq. 37).

    ``locations`` says per cable where its load cell sits (``"robot_base"`` between the last pulley
    and the base disk, or ``"actuator"`` between actuator and first pulley); it decides where
    measured tensions enter and which modelled tension :attr:`Transfer.T_at` reports.
    ``reversal_band_mm`` > 0 spreads a friction reversal over that much material travel (a smooth
    dead-zone inverse); 0 flips it at once (the exact inverse of the forward model).
    ``friction_law``: the disk friction's law (None or the capstan shape: eq. 16-24);
    ``cycle_s``: the time between :meth:`step` calls (s), needed by a speed-dependent law.
    """

    def __init__(
        self,
        params: RobotParams,
        effects: Effects | None = None,
        locations: Sequence[Location] | None = None,
        reversal_band_mm: float = 0.0,
        friction_law: FrictionLawShape | None = None,
        cycle_s: float = 0.0,
    ) -> None:
        self.params = params
        self.effects = Effects() if effects is None else effects
        law = None if friction_law is None or friction_law.capstan else friction_law
        self.friction_law = law
        self.transfer = (
            ForceTransfer(params, self.effects)
            if law is None
            else LawTransfer(params, self.effects, law)
        )
        self._speed_law = law is not None and law.speed_dependent
        if self._speed_law and not cycle_s > 0.0:
            raise ModelError("a speed-dependent friction law needs the step period cycle_s > 0")
        self.cycle_s = float(cycle_s)
        #: The speed memory's blend per step (1 - exp(-cycle_s / SPEED_MEMORY_S)): fixed at start.
        self._speed_blend = -math.expm1(-self.cycle_s / SPEED_MEMORY_S) if self._speed_law else 0.0
        K = params.n_cables
        self.locations: list[Location] = (
            ["robot_base"] * K if locations is None else list(locations)
        )
        if len(self.locations) != K:
            raise ModelError(f"need one load-cell location per cable ({K})")
        self.reversal_band_mm = float(reversal_band_mm)
        self._lengths = [s.length_mm for s in params.segments]
        self._T0 = [c.pretension_N for c in params.cables]
        self._B = cable_matrix_x(params)
        # The loop converts one pose three times a cycle (ideal displacements, compensation,
        # tip): the last conversion is kept, keyed by the pose's bytes.
        self._flat_key = b""
        self._flat_xs: list[float] = []

    def _flat(self, psi: np.ndarray | Sequence[Sequence[float]]) -> list[float]:
        """:func:`psi_to_flat_x` of ``psi``, the last one kept (do not mutate the list)."""
        a = np.asarray(psi, dtype=float)
        key = a.tobytes()
        if key != self._flat_key or not self._flat_xs:
            self._flat_xs = psi_to_flat_x(a)
            self._flat_key = key
        return self._flat_xs

    @property
    def n_segments(self) -> int:
        return self.params.n_segments

    @property
    def n_cables(self) -> int:
        return self.params.n_cables

    # ------------------------------------------------------------------ stateless
    def q_geometric(self, psi: np.ndarray) -> np.ndarray:
        """Ideal inverse kinematics q_geom (K,), mm: eq. 4 (or exact chords, per ``effects``)."""
        xs = self._flat(psi)
        if self.effects.geometry == "cc":
            return self._B @ np.asarray(xs)
        return np.asarray(self.transfer.pose(xs).q_geom)

    def compensate(
        self,
        psi: np.ndarray,
        s: Sequence[float] | FrictionState,
        mode: str = "model",
        measured_N: Sequence[float] | None = None,
    ) -> Transfer:
        """Eq. 37 at pose ``psi`` for friction fractions ``s`` (+1 pulling, -1 paying out).

        Returns the whole :class:`Transfer` (``q`` is q~ = q_geom + delta_in + delta_out).
        ``mode="measured"`` uses ``measured_N`` (load-cell tensions at :attr:`locations`, NaN
        where missing) in place of the modelled tensions.
        """
        s_list = list(s.s) if isinstance(s, FrictionState) else [float(v) for v in s]
        xs = psi_to_flat_x(psi)
        if mode == "measured":
            if measured_N is None:
                raise ModelError("mode 'measured' needs load-cell tensions")
            return self.measured_transfer(xs, s_list, [float(v) for v in measured_N])
        if mode not in MODES:
            raise ModelError(f"compensation mode must be one of {MODES}, not {mode!r}")
        return self.transfer.evaluate(xs, s_list)

    def measured_transfer(
        self, xs: list[float], s: list[float], measured_N: list[float], pose: Pose | None = None
    ) -> Transfer:
        """The chain with load-cell tensions in place of the modelled ones, common mode pinned.

        Each reading (N, at :attr:`locations`; NaN: use the model) is carried to the anchor
        through the friction of state ``s`` (eq. 23, 29-32). What the compensation then feeds
        forward is the stretch those tensions cause (eq. 33-37), with one exception: the
        *pretension mode* of each segment, the combination of its own cables' mean tensions
        that produces no moment (for three cables at 120 deg about [1, 1, 1]; in general the
        null vector n of the 2 x m arm matrix, Qi eq. 10). The load cells cannot be trusted
        along it in a feedforward: a common rise of the measured tensions commands a common
        extra pull delta = T L / EA, which raises the tensions by T L_true / EA_true, a loop
        gain of about 1 (a neutrally stable integrator that, with noise and lag, drifts the
        cables slack or tight; seen on the simulated rig). So the measured mean tensions of a
        segment's own cables are shifted along n until the least-tensioned one sits at its
        pretension, the same rule as the model's statics; the moment they carry (the part that
        bends the robot) is the measured one. A segment with a missing reading, or whose null
        vector is not all of one sign, is used as measured.
        """
        tr = self.transfer
        P = tr.pose(xs) if pose is None else pose
        Fb, Eb = tr.factors(P, s)
        K = self.n_cables
        T: list[float] = [0.0] * K
        missing = [False] * K
        T_model: list[float] | None = None
        for k in range(K):
            v = measured_N[k]
            if v != v:  # NaN: no reading for this cable
                if T_model is None:
                    T_model = tr.statics(P, Fb)
                T[k] = T_model[k]
                missing[k] = True
                continue
            Tb = v if self.locations[k] == "robot_base" else tr.base_from_actuator(k, v, s[k])
            T[k] = Tb * math.exp(-Eb[k])
        for i in range(self.n_segments):
            own = list(self.params.cables_of(i))
            if any(missing[k] for k in own):
                continue
            n = _null_vector([P.arm[k][i] for k in own])
            if n is None:
                continue
            M = [T[k] * Fb[k][i] for k in own]
            c = max((self._T0[k] - M[j]) / n[j] for j, k in enumerate(own))
            for j, k in enumerate(own):
                T[k] = (M[j] + c * n[j]) / Fb[k][i]
        return tr.evaluate(xs, s, T_distal=T, pose=P)

    # ------------------------------------------------------------------ stateful
    def new_state(self, friction: FrictionState | None = None) -> CompensationState:
        K = self.n_cables
        f = FrictionState.initial(K) if friction is None else friction
        return CompensationState(
            s=list(f.s),
            w_mm=list(f.w_mm),
            effect_states=[e.new_state(K) for e in self.effects.actuator],
        )

    def step(
        self,
        psi: np.ndarray,
        state: CompensationState,
        mode: str = "model",
        measured_N: Sequence[float] | None = None,
    ) -> Transfer:
        """Compensation at the next desired pose, updating the friction memory in ``state``.

        The friction fraction of each cable follows the material flow at the base hole:
        w = q_geom + delta_in rising -> +1, falling -> -1, unchanged -> kept (stick memory);
        with ``reversal_band_mm`` it moves by dw/band instead of jumping. The model tensions
        decide the direction in every mode, so measured noise cannot chatter the state.
        """
        tr = self.transfer
        xs = self._flat(psi)
        P = tr.pose(xs)
        if self._speed_law:
            self._follow_speeds(P.q_geom, state)
        res = tr.evaluate(xs, state.s, pose=P)
        changed = False
        band = self.reversal_band_mm
        s_old, w_old, w_new = state.s, state.w_mm, res.w
        new_s = list(s_old)
        for k in range(tr.K):
            dw = w_new[k] - w_old[k]
            sk = s_old[k]
            ns = band_update(sk, dw, band) if band > 0.0 else direction_update(sk, dw, 1e-12)
            if ns != sk:
                new_s[k] = ns
                changed = True
        if changed:
            res = tr.evaluate(xs, new_s, pose=P)
        state.s = new_s
        state.w_mm = list(res.w)
        if mode == "measured":
            if measured_N is None:
                raise ModelError("mode 'measured' needs load-cell tensions")
            res = self.measured_transfer(xs, new_s, [float(v) for v in measured_N], P)
        state.last = res
        return res

    def _follow_speeds(self, q_geom: list[float], state: CompensationState) -> None:
        """Each cable's speed |dq_geom| / cycle_s, lagged by SPEED_MEMORY_S, into the law."""
        dt = self.cycle_s
        if state.q_geom_mm is None or state.speed_mm_s is None:
            v = [0.0] * len(q_geom)
        else:
            a = self._speed_blend
            v = [
                vo + a * (abs(qn - qo) / dt - vo)
                for vo, qn, qo in zip(state.speed_mm_s, q_geom, state.q_geom_mm, strict=True)
            ]
        state.q_geom_mm = list(q_geom)
        state.speed_mm_s = v
        assert isinstance(self.transfer, LawTransfer)
        self.transfer.set_speeds(v)

    def actuator_command(self, q_cable_mm: np.ndarray, state: CompensationState) -> np.ndarray:
        """Apply the inverse of :attr:`Effects.actuator` (actuator-first order), mm."""
        q = np.asarray(q_cable_mm, dtype=float)
        effs = self.effects.actuator
        for j in range(len(effs) - 1, -1, -1):
            q = effs[j].to_actuator(q, state.effect_states[j])
        return q


def _null_vector(arms: list[tuple[float, float]]) -> list[float] | None:
    """Positive n with sum_j n_j arms_j = 0 (max component 1), for 2 or 3 arms; else None.

    Three arms: n = (a2 x a3, a3 x a1, a1 x a2) (2D cross products); two opposed arms:
    n = (|a2|, |a1|). None when the arms admit no such vector of one sign.
    """
    if len(arms) == 3:
        (x1, y1), (x2, y2), (x3, y3) = arms
        n = [x2 * y3 - y2 * x3, x3 * y1 - y3 * x1, x1 * y2 - y1 * x2]
    elif len(arms) == 2:
        (x1, y1), (x2, y2) = arms
        if abs(x1 * y2 - y1 * x2) > 1e-9 * (x1 * x1 + y1 * y1 + x2 * x2 + y2 * y2):
            return None
        n = [math.hypot(x2, y2), math.hypot(x1, y1)]
    else:
        return None
    if all(v < 0.0 for v in n):
        n = [-v for v in n]
    top = max(n)
    if top <= 0.0 or min(n) <= 1e-9 * top:
        return None
    return [v / top for v in n]


class CCDiskModel(Compensator):
    """The constant-curvature disk design as the control loop's ``RobotModelPort`` (built from a
    rig config by :func:`cdcr_ctl.config.build_model.build_model`)."""

    def q_nominal(self, psi: np.ndarray) -> np.ndarray:
        """Ideal inverse kinematics (mm pulled in), no compensation."""
        return self.q_geometric(psi)

    def q_command(
        self,
        psi: np.ndarray,
        q_nominal: np.ndarray,
        state: object,
        mode: str,
        measured_N: np.ndarray | None,
    ) -> np.ndarray:
        """q_nominal + delta of ``mode`` (off/model/measured), then the actuator effects, mm.

        Every effect of the model acts on every cycle: the force-transfer chain (friction,
        elongation, coupling, gravity, pulleys) through delta, and the transmission effects
        (the cables' dead zone with its direction memory, Yang et al. 2022 eq. 13-17) through
        :meth:`actuator_command`. ``state`` is the object from :meth:`new_state`; the control
        loop owns it and passes it every cycle (mutated here). Mode ``off`` sends q_nominal
        alone but still tracks the friction and dead-zone memories, so that switching modes
        mid-run starts from the right state.
        """
        if not isinstance(state, CompensationState):
            raise ModelError("q_command needs the state made by new_state()")
        if mode not in MODES:
            raise ModelError(f"compensation mode must be one of {MODES}, not {mode!r}")
        res = self.step(psi, state, "model" if mode == "off" else mode, measured_N)
        if mode == "off":
            q = np.asarray(q_nominal, dtype=float)
            if self.effects.actuator:
                # The transmission memories (dead-zone direction) follow the command in every
                # mode, so switching mode mid-run starts from the right pre-travel; ``off``
                # sends the bare geometry.
                self.actuator_command(q, state)
            return q
        # q_nominal + (q - q_geom), element by element as numpy would (same rounding)
        qn = np.asarray(q_nominal, dtype=float).tolist()
        q = np.array([n + (a - b) for n, a, b in zip(qn, res.q, res.q_geom, strict=True)])
        if not self.effects.actuator:
            return q
        return self.actuator_command(q, state)

    def tip(self, psi: np.ndarray) -> np.ndarray:
        """Tip position (mm, base frame), eq. 1-3."""
        return np.array(tip_position_fast(self._flat(psi), self._lengths))
