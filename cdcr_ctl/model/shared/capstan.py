"""Improved capstan equation for the guide pulleys (Qi et al. 2023 eq. 25-32).

After Jung, Pan and Kang, Mechanism and Machine Theory 2008: bending rigidity of the cable and
non-linear friction f = alpha N^n.

Eq. 29, with rho = R / r_s (pulley radius over cable radius, NOTES) and phi the wrap angle (rad):

    T'' + c T^((1-n)/n) T' - rho T = 0,    c = (rho / n) ((1 + rho) / (alpha rho))^(1/n)

Derivation (checks the printed form): from eq. 27 with dM = 0, the shear is Q = r_s f'/R' where
the contact radius R' = R + r_s, so Q = f'/(1 + rho); then T' = f' - Q = f' rho/(1 + rho) and
N' = T - Q'. Reading the friction law as f = alpha N^n for the accumulated quantities,
f = (1 + rho) T / rho and N^(n-1) N' = f'/(alpha n) give N' = (1/n) ((1+rho)/(alpha rho))^(1/n)
T^((1-n)/n) T', and Q' = T - N' with Q = T'/rho is eq. 29. n = 1 gives the linear ODE
T'' + ((1 + rho)/alpha) T' - rho T = 0 whose growing root tends to alpha as rho -> inf: the
classical capstan T_in/T_out = exp(alpha phi).

Boundary values (eq. 30-31 with theta_1 = 0): T(0) = T1 (the low, outgoing tension), T'(0) = 0.
The tension ratio (eq. 32, the printed rho^2 in the denominator is a typo, NOTES) is the
resultant of axial tension and shear Q = T'/rho over the outgoing tension:

    kappa(phi) = sqrt(rho^2 T(phi)^2 + T'(phi)^2) / (rho T(0)),   kappa(0) = 1.

Check value (NOTES), verified: rho = 10, alpha = 0.6, n = 1 gives kappa(pi) = 5.147 against the
classical exp(0.6 pi) = 6.59. For n = 1 the ratio does not depend on T1; for n < 1 it does
(through T^((1-n)/n), tension in N), so a pulley is tabulated over T1 at its fixed wrap.
Paying out (actuator side low) inverts the ratio: the robot side is kappa times the actuator side.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from cdcr_ctl.errors import ModelError

#: Tension range (N) of the pulley tables; outside it the ratio is held at the edge value.
TABLE_T_MIN_N = 1e-3
TABLE_T_MAX_N = 1e3


def classical_ratio(alpha: float, phi: float) -> float:
    """Classical capstan (Euler-Eytelwein) T_in/T_out = exp(alpha phi)."""
    return math.exp(alpha * phi)


def damping_coefficient(rho: float, alpha: float, n: float) -> float:
    """c of eq. 29: (rho/n) ((1 + rho)/(alpha rho))^(1/n); alpha in N^(1-n)."""
    return (rho / n) * ((1.0 + rho) / (alpha * rho)) ** (1.0 / n)


def _roots_linear(rho: float, alpha: float) -> tuple[float, float]:
    """Roots of l^2 + c l - rho = 0 for n = 1, written without cancellation."""
    c = (1.0 + rho) / alpha
    root = math.sqrt(c * c + 4.0 * rho)
    lam1 = 2.0 * rho / (c + root)  # small positive root
    lam2 = -0.5 * (c + root)
    return lam1, lam2


@dataclass(frozen=True)
class CapstanProfile:
    """Solution of eq. 29-31 on a grid: T, T' and the running integral of T over phi."""

    phi: np.ndarray
    T: np.ndarray
    dT: np.ndarray
    int_T: np.ndarray
    rho: float
    T1: float

    @property
    def kappa(self) -> np.ndarray:
        """Eq. 32 (corrected) on the grid: sqrt(rho^2 T^2 + T'^2) / (rho T(0))."""
        return np.sqrt(self.rho**2 * self.T**2 + self.dT**2) / (self.rho * self.T1)


def solve_profile(
    rho: float, alpha: float, n: float, phi: np.ndarray | float, T1: float = 1.0
) -> CapstanProfile:
    """Integrate eq. 29 from phi = 0 with T(0) = T1 (N), T'(0) = 0, onto the sorted grid ``phi``.

    n = 1 uses the exact exponential solution; n < 1 LSODA of :func:`scipy.integrate.solve_ivp`
    (stiff/non-stiff switching: the equation is stiff for large rho or large tension).
    alpha = 0 is a frictionless pulley (T constant).
    """
    grid = np.atleast_1d(np.asarray(phi, dtype=float))
    if grid[0] != 0.0:
        grid = np.concatenate(([0.0], grid))
        drop_first = True
    else:
        drop_first = False
    if np.any(np.diff(grid) < 0) or T1 <= 0 or rho <= 0 or not 0 < n <= 1:
        raise ModelError("capstan: need sorted phi >= 0, T1 > 0, rho > 0, 0 < n <= 1")
    if alpha == 0.0:
        T = np.full_like(grid, T1)
        dT = np.zeros_like(grid)
        iT = T1 * grid
    elif n == 1.0:
        l1, l2 = _roots_linear(rho, alpha)
        e1, e2 = np.exp(l1 * grid), np.exp(l2 * grid)
        k = T1 / (l1 - l2)
        T = k * (-l2 * e1 + l1 * e2)
        dT = k * l1 * l2 * (e2 - e1)
        iT = k * (-l2 / l1 * (e1 - 1.0) + l1 / l2 * (e2 - 1.0))
    else:
        c = damping_coefficient(rho, alpha, n)
        p = (1.0 - n) / n

        def rhs(_phi: float, y: np.ndarray) -> list[float]:
            T_, Z, _ = y
            Tp = max(T_, 1e-300) ** p
            return [Z, -c * Tp * Z + rho * T_, T_]

        def jac(_phi: float, y: np.ndarray) -> list[list[float]]:
            T_, Z, _ = y
            Tc = max(T_, 1e-300)
            return [
                [0.0, 1.0, 0.0],
                [-c * p * Tc ** (p - 1.0) * Z + rho, -c * Tc**p, 0.0],
                [1.0, 0.0, 0.0],
            ]

        sol = solve_ivp(
            rhs,
            (0.0, float(grid[-1]) if grid[-1] > 0 else 1e-12),
            [T1, 0.0, 0.0],
            method="LSODA",
            t_eval=grid,
            rtol=1e-10,
            atol=1e-12 * T1,
            jac=jac,
        )
        if not sol.success:
            raise ModelError(f"capstan ODE (eq. 29) failed: {sol.message}")
        T, dT, iT = sol.y
    if drop_first:
        grid, T, dT, iT = grid[1:], T[1:], dT[1:], iT[1:]
    return CapstanProfile(phi=grid, T=T, dT=dT, int_T=iT, rho=rho, T1=T1)


def improved_ratio(rho: float, alpha: float, n: float, phi: float, T1: float = 1.0) -> float:
    """kappa = T_in/T_out after a wrap of ``phi`` rad, eq. 32 (corrected); T1 = T_out in N."""
    if phi == 0.0:
        return 1.0
    return float(solve_profile(rho, alpha, n, phi, T1).kappa[-1])


def kappa_table(
    rho: float, alpha: float, n: float, phi_grid: np.ndarray, T1: float = 1.0
) -> np.ndarray:
    """kappa(phi) on a grid (for plots and load-time tables of eq. 32)."""
    return solve_profile(rho, alpha, n, np.asarray(phi_grid, dtype=float), T1).kappa


@functools.lru_cache(maxsize=64)
def _tension_table(
    rho: float, wrap_rad: float, alpha: float, n: float, points: int
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(ln kappa, mean ratio) on a log grid of the low tension T1 (N) for n < 1; cached per
    pulley/cable pair.

    Eq. 29-31 for every grid tension at once: one LSODA integration of the ``points``
    independent profiles stacked (T, T', integral of T per tension, interleaved), whose Jacobian
    is banded (two diagonals below, one above) and handed to LSODA packed. Each component keeps
    :func:`solve_profile`'s tolerances (rtol 1e-10, atol 1e-12 T1): the shared step is the one
    the most demanding profile needs, so no profile is solved less accurately than alone, in a
    single integration instead of ``points``.
    """
    T1 = np.exp(np.linspace(math.log(TABLE_T_MIN_N), math.log(TABLE_T_MAX_N), points))
    c = damping_coefficient(rho, alpha, n)
    p = (1.0 - n) / n

    def rhs(_phi: float, y: np.ndarray) -> np.ndarray:
        T_, Z = y[0::3], y[1::3]
        out = np.empty_like(y)
        out[0::3] = Z
        out[1::3] = -c * np.maximum(T_, 1e-300) ** p * Z + rho * T_
        out[2::3] = T_
        return out

    def jac(_phi: float, y: np.ndarray) -> np.ndarray:
        # Packed band storage: row uband + i - j holds d(dy_i)/d(y_j), uband = 1.
        Tc, Z = np.maximum(y[0::3], 1e-300), y[1::3]
        band = np.zeros((4, y.size))
        band[0, 1::3] = 1.0  # dT/dphi by T'
        band[1, 1::3] = -c * Tc**p  # dT'/dphi by T'
        band[2, 0::3] = -c * p * Tc ** (p - 1.0) * Z + rho  # dT'/dphi by T
        band[3, 0::3] = 1.0  # d(int T)/dphi by T
        return band

    y0 = np.zeros(3 * points)
    y0[0::3] = T1
    sol = solve_ivp(
        rhs,
        (0.0, wrap_rad),
        y0,
        method="LSODA",
        t_eval=[wrap_rad],
        rtol=1e-10,
        atol=np.repeat(1e-12 * T1, 3),
        jac=jac,
        lband=2,
        uband=1,
    )
    if not sol.success:
        raise ModelError(f"capstan ODE (eq. 29) failed: {sol.message}")
    T, dT, iT = sol.y[0::3, -1], sol.y[1::3, -1], sol.y[2::3, -1]
    lnk = np.log(np.sqrt(rho**2 * T**2 + dT**2) / (rho * T1))
    return tuple(lnk.tolist()), tuple((iT / (wrap_rad * T1)).tolist())


class PulleyTransfer:
    """Tension transfer and wrapped-length elongation of one cable over one pulley.

    Built once at load time: for n = 1 two constants, for n < 1 a table over the outgoing (low)
    tension T_lo on a log grid, interpolated linearly in (ln T_lo, ln kappa). The hot-path methods
    take plain floats. ``s`` in [-1, 1] is the mobilised friction fraction of the cable
    (:mod:`cdcr_ctl.model.shared.friction`): +1 sliding while pulled in (the actuator side is high),
    -1 sliding while paid out (the robot side is high); in between, ln(T_high/T_low) = |s| ln kappa.
    """

    def __init__(
        self,
        radius_mm: float,
        wrap_rad: float,
        alpha: float,
        n: float,
        cable_radius_mm: float,
        points: int = 121,
    ) -> None:
        self.rho = radius_mm / cable_radius_mm
        self.wrap_rad = wrap_rad
        #: wrapped length of the cable centreline, (R + r_s) phi (mm)
        self.wrapped_mm = (radius_mm + cable_radius_mm) * wrap_rad
        self.frictionless = alpha == 0.0 or wrap_rad == 0.0
        self.constant = self.frictionless or n == 1.0
        if self.frictionless:
            self._lnk = 0.0
            self._mean = 1.0
        elif self.constant:
            prof = solve_profile(self.rho, alpha, 1.0, wrap_rad)
            self._lnk = math.log(float(prof.kappa[-1]))
            self._mean = float(prof.int_T[-1]) / wrap_rad
        else:
            lnk, mean = _tension_table(self.rho, wrap_rad, alpha, n, points)
            self._x0 = math.log(TABLE_T_MIN_N)
            self._dx = (math.log(TABLE_T_MAX_N) - self._x0) / (points - 1)
            self._n_pts = points
            self._lnk_tab = list(lnk)
            self._mean_tab = list(mean)
            #: per table piece j (slope m_j, intercept a_j - m_j y_j) of ln kappa over ln T
            self._pieces = []
            for j in range(points - 1):
                m = (lnk[j + 1] - lnk[j]) / self._dx
                self._pieces.append((m, lnk[j] - m * (self._x0 + j * self._dx)))

    # ------------------------------------------------------------------ table look-up
    def _lookup(self, lnT: float) -> tuple[float, float]:
        """(ln kappa, mean ratio) of the table at ln T (held at the edge values outside the
        range): the one table look-up, linear in ln T between grid points."""
        u = (lnT - self._x0) / self._dx
        if u <= 0.0:
            return self._lnk_tab[0], self._mean_tab[0]
        if u >= self._n_pts - 1:
            return self._lnk_tab[-1], self._mean_tab[-1]
        j = int(u)
        f = u - j
        a, b = self._lnk_tab[j], self._lnk_tab[j + 1]
        c, d = self._mean_tab[j], self._mean_tab[j + 1]
        return a + f * (b - a), c + f * (d - c)

    def ln_kappa(self, T_low_N: float) -> float:
        """ln kappa for a low-side tension (N)."""
        return self._lnk_mean(T_low_N)[0]

    def mean_ratio(self, T_low_N: float) -> float:
        """(1/phi) integral of T over the wrap divided by T_low, fully sliding (|s| = 1)."""
        return self._lnk_mean(T_low_N)[1]

    def raise_low(self, T_low_N: float, frac: float) -> float:
        """High-side tension for a low-side tension and a mobilised fraction ``frac`` in [0, 1].

        Tensions <= 0 (only met inside solver iterations) are scaled linearly with the edge ratio.
        """
        return T_low_N * math.exp(frac * self.ln_kappa(T_low_N))

    def lower_high(self, T_high_N: float, frac: float) -> float:
        """Low-side tension whose :meth:`raise_low` is ``T_high_N``.

        Solves y + frac ln kappa(y) = ln T_high for y = ln T_low on the table, which is linear in
        ln T between grid points: on the piece j holding y, ln kappa = a_j + m_j (y - y_j), so
        y = (ln T_high - frac (a_j - m_j y_j)) / (1 + frac m_j) exactly (what Newton's method on
        the table converges to); started on the piece of ln T_high - frac ln kappa(T_high) and
        moved to the piece the solution lies on (one step when kappa is constant)."""
        if self.constant:
            return T_high_N * math.exp(-frac * self._lnk)
        if T_high_N <= 0.0:
            return T_high_N * math.exp(-frac * self._lnk_tab[0])
        return math.exp(self._ln_low(math.log(T_high_N), frac))

    def _ln_low(self, lnH: float, frac: float) -> float:
        """ln of :meth:`lower_high` on the table, from ln T_high (see there)."""
        tab, x0, dx, last = self._lnk_tab, self._x0, self._dx, self._n_pts - 1
        y = lnH - frac * self._lookup(lnH)[0]
        piece = -2
        pieces = self._pieces
        for _ in range(last + 2):
            u = (y - x0) / dx
            j = -1 if u <= 0.0 else (last if u >= last else int(u))
            if j == piece:
                break
            piece = j
            if j < 0:  # held at the edge values outside the table
                y = lnH - frac * tab[0]
            elif j == last:
                y = lnH - frac * tab[-1]
            else:
                m, c = pieces[j]
                y = (lnH - frac * c) / (1.0 + frac * m)
        return y

    def to_actuator(self, T_robot_N: float, s: float) -> float:
        """Tension on the actuator side of the pulley from the robot side (N)."""
        return self.raise_low(T_robot_N, s) if s >= 0.0 else self.lower_high(T_robot_N, -s)

    def to_robot(self, T_actuator_N: float, s: float) -> float:
        """Tension on the robot side of the pulley from the actuator side (N)."""
        return self.lower_high(T_actuator_N, s) if s >= 0.0 else self.raise_low(T_actuator_N, -s)

    def _lnk_mean(self, T_low_N: float) -> tuple[float, float]:
        """(:meth:`ln_kappa`, :meth:`mean_ratio`) at one low-side tension (N): one logarithm and
        one table position for both."""
        if self.constant:
            return self._lnk, self._mean
        if T_low_N <= 0.0:
            return self._lnk_tab[0], self._mean_tab[0]
        return self._lookup(math.log(T_low_N))

    def to_actuator_stretch(self, T_robot_N: float, s: float, T0_N: float) -> tuple[float, float]:
        """(:meth:`to_actuator`, :meth:`stretch_integral` over this pulley) from the robot-side
        tension: the same floats as the two calls, with the table looked up once where the low
        side is the robot side (pulled in, s >= 0: the common case). It runs six times per
        evaluation of the chain: ``benchmarks/bench_hot_paths.py`` measures it against the two
        calls."""
        T = T_robot_N
        if self.frictionless:
            return self.to_actuator(T, s), self.stretch_integral(self.to_actuator(T, s), T, s, T0_N)
        if self.constant or T <= 0.0:
            return self._stretch_slow(T, s, T0_N)
        if s >= 0.0:
            low = T
        else:
            Tn = math.exp(self._ln_low(math.log(T), -s))  # lower_high(T, -s)
            low = Tn if Tn <= T else T
        lnk, mean = self._lookup(math.log(low))  # low > 0
        if s >= 0.0:
            Tn = T * math.exp(s * lnk)  # raise_low(T, s)
            if Tn < T:  # (only with a negative ln kappa) the actuator side is the low one
                lnk, mean = self._lnk_mean(Tn)
                low = Tn
        f = abs(s)
        if f < 1.0 and lnk > 0.0:
            mean = 1.0 + (mean - 1.0) * math.expm1(f * lnk) / math.expm1(lnk)
        return Tn, (low * mean - T0_N) * self.wrapped_mm

    def _stretch_slow(self, T: float, s: float, T0_N: float) -> tuple[float, float]:
        """:meth:`to_actuator_stretch` of a constant-ratio pulley or a tension <= 0."""
        if s >= 0.0:
            lnk, mean = self._lnk_mean(T)
            Tn = T * math.exp(s * lnk)  # raise_low(T, s)
            if Tn < T:  # (only with a negative ln kappa) the actuator side is the low one
                lnk, mean = self._lnk_mean(Tn)
                low = Tn
            else:
                low = T
        else:
            Tn = self.lower_high(T, -s)
            low = Tn if Tn <= T else T
            lnk, mean = self._lnk_mean(low)
        f = abs(s)
        if f < 1.0 and lnk > 0.0:
            mean = 1.0 + (mean - 1.0) * math.expm1(f * lnk) / math.expm1(lnk)
        return Tn, (low * mean - T0_N) * self.wrapped_mm

    def stretch_integral(self, T_a_N: float, T_b_N: float, s: float, T0_N: float) -> float:
        """Integral of (T - T0) over the wrapped length (N mm); T_a, T_b the two side tensions.

        Fully sliding, the profile is the eq. 29 solution, whose mean is ``mean_ratio`` times the
        low tension. For a partly mobilised fraction f = |s| the mean ratio is taken as
        1 + (m - 1)(kappa^f - 1)/(kappa - 1): exact at f = 0 (uniform) and f = 1, monotone between.
        """
        low = T_a_N if T_a_N <= T_b_N else T_b_N
        if self.frictionless:
            return (low - T0_N) * self.wrapped_mm
        f = abs(s)
        lnk = self.ln_kappa(low)
        m = self.mean_ratio(low)
        if f < 1.0 and lnk > 0.0:
            m = 1.0 + (m - 1.0) * math.expm1(f * lnk) / math.expm1(lnk)
        return (low * m - T0_N) * self.wrapped_mm


__all__ = [
    "CapstanProfile",
    "PulleyTransfer",
    "classical_ratio",
    "damping_coefficient",
    "improved_ratio",
    "kappa_table",
    "solve_profile",
]
