"""The settings and results of a joint identification: :class:`FitOptions`, :class:`Estimate`,
:class:`Identification` and the residual kinds (see :mod:`cdcr_ctl.identify.estimator`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cdcr_ctl.identify.dwell import DwellPoint
from cdcr_ctl.identify.parameters import FitParameter, NotIdentified
from cdcr_ctl.model.cc_disk.friction_shape import FrictionLawShape
from cdcr_ctl.model.cc_disk.params import RobotParams

RESIDUAL_KINDS = ("tip", "cell", "moment", "compat")


@dataclass(frozen=True)
class FitOptions:
    """Noise floors (standard deviations of a dwell mean) and solver settings.

    ``tip_floor_mm``: tracker; ``tension_floor_N``: load cell; ``q_floor_mm``: drive position
    (counts resolution and following error); ``moment_floor_Nmm``: model tolerance of the moment
    balance. ``slack_N``: below it a cable's compatibility is not used. ``slack_compat``: write
    compatibility as q(T) - max(q_act, q(T=0)), which a slack cable (longer than its path at
    zero tension) meets with T = 0 and a taut one as before (for logs without load cells, where
    slack is not measured). ``max_nfev``: function
    evaluations per stage. ``max_rel_ci``: a parameter whose 95 % half-interval exceeds this
    fraction of its value is reported as poorly identified (and, for pulleys with cells at the
    robot base, put back to nominal and the fit repeated without it). ``play_mm``: per cable,
    the play (mm) the friction states and the play-state mask assume (None: the config's
    ``backlash_mm``; :func:`~cdcr_ctl.identify.estimator.identify` sets it to the fitted play
    when it re-assigns the states).
    """

    tip_floor_mm: float = 0.005
    tension_floor_N: float = 0.002
    q_floor_mm: float = 0.001
    moment_floor_Nmm: float = 0.005
    slack_N: float = 0.1
    max_nfev: int = 60
    max_rel_ci: float = 0.5
    slack_compat: bool = False
    play_mm: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Estimate:
    """A fitted parameter: value, standard error and 95 % interval (natural units)."""

    parameter: FitParameter
    value: float
    std: float
    ci95: tuple[float, float]
    at_bound: bool = False
    ci_at_bound: bool = False  # the interval reached a bound and was clipped there

    @property
    def name(self) -> str:
        return self.parameter.name

    @property
    def nominal(self) -> float:
        return self.parameter.nominal

    @property
    def change_text(self) -> str:
        """The change from nominal: in % of it, or absolute when the nominal is 0."""
        nom = self.parameter.nominal
        if nom:
            return f"{100.0 * (self.value - nom) / nom:.1f}%"
        return f"{self.value - nom:+.4g}"

    @property
    def change_pct(self) -> float:
        nom = self.parameter.nominal
        return 100.0 * (self.value - nom) / nom if nom else math.nan

    @property
    def rel_halfwidth(self) -> float:
        lo, hi = self.ci95
        return 0.5 * (hi - lo) / abs(self.value) if self.value else math.inf


@dataclass
class Identification:
    """Result of :func:`identify`: fitted parameters, what stayed nominal, residual statistics.

    ``rms_before``/``rms_after``: RMS of each residual kind in its own unit (mm, N, N mm, mm)
    with the nominal and the fitted parameters (poses and tensions re-estimated for each).
    ``residuals_before``/``residuals_after``: per kind, (point index, value) arrays for plots.
    ``poses``: fitted bending vectors per point (N, 2S); ``s``: friction fractions (N, K).
    ``friction_law``: the disk friction law the coefficients were fitted under (None: the
    capstan law), read from ``friction_law_source``.
    """

    nominal: RobotParams
    fitted: RobotParams
    estimates: list[Estimate]
    fixed: list[NotIdentified]
    points: list[DwellPoint]
    rms_before: dict[str, float]
    rms_after: dict[str, float]
    residuals_before: dict[str, tuple[np.ndarray, np.ndarray]]
    residuals_after: dict[str, tuple[np.ndarray, np.ndarray]]
    poses: np.ndarray
    s: np.ndarray
    chi2_reduced: float
    n_residuals: int
    n_unknowns: int
    stages: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    friction_law: FrictionLawShape | None = None
    friction_law_source: str = "the rig config"

    @property
    def friction_law_text(self) -> str | None:
        """One line naming the law fitted under; None for the capstan law."""
        law = self.friction_law
        if law is None or law.capstan:
            return None
        parts = [f"wrap exponent {law.exponent:g}"]
        if law.viscous_s_per_mm:
            parts.append(f"viscous {law.viscous_s_per_mm:g} s/mm")
        if law.breakaway:
            parts.append(
                f"breakaway {law.breakaway:g} over {law.breakaway_mm_s:g} mm/s "
                "(at rest in the dwells: mu_disk is the Coulomb coefficient)"
            )
        return (
            "disk friction law: robot.friction_law "
            + ", ".join(parts)
            + f" (from {self.friction_law_source})"
        )

    def estimate(self, name: str) -> Estimate:
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)
