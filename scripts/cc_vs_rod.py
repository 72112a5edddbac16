"""How far the constant-curvature shape carries under a tip load: CC per segment vs a rod.

    .venv/bin/python scripts/cc_vs_rod.py [--segments 200 200] [--ei 2945] [--bend-deg 45]

A planar robot of two segments (200 mm each by default, the size of Rao et al. 2021's), a
superelastic NiTi backbone (EI = 2945 N mm^2: E 60 GPa, 1 mm rod), tendons parallel to the
backbone at a fixed offset. Tensions are set so that, unloaded, each segment bends ``bend-deg``;
then a tip force of 0.02-0.1 N (2-10 g) acts along -z (gravity on a payload when the robot
stands upright) and along x (sideways).

Two models of the same robot and tensions:

* **rod** (Kirchhoff, inextensible, unshearable): cutting rod and tendons at arc s, the distal
  part carries the tendons' tension at their offset (a moment T r per tendon crossing s, the same
  at every s: tendons parallel to the backbone) and the tip force, so
  EI theta'(s) = M_t(s) + (z_L - z(s)) F_x - (x_L - x(s)) F_z, p = (x, z),
  p' = (sin theta, cos theta) (theta from z towards x; the bracket is the moment of F about
  the cut that turns z towards x). Solved by fixed
  point on p(L) (relaxed, 0.3 of each update) with 2000 steps of the midpoint rule (p(L) to 0.1 um
  between iterations; 4000 steps change the tips by < 0.01 mm).
* **cc**: one constant-curvature arc per segment (Qi et al. 2023 eq. 1-3, the controller's
  shape), bends from the minimum of the potential energy sum EI th_i^2/(2 l_i) - M_i th_i
  - F . p_tip(th) (virtual work, eq. 7-9 with W_e = the tip force).

Printed: the tip of each, their distance (mm) and its share of the robot's length.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.optimize import minimize


def rod_tip(lengths, EI, M_seg, F, n=2000):
    """Tip (x, z) mm and shape of the planar rod (see module doc)."""
    L = sum(lengths)
    s = np.linspace(0.0, L, n + 1)
    ds = L / n
    # tendon moment at arc s: the tendons of every segment whose anchor lies beyond s
    ends = np.cumsum(lengths)
    Mt = [sum(M for M, e in zip(M_seg, ends, strict=True) if si < e - 1e-12) for si in s]
    Fx, Fz = float(F[0]), float(F[1])
    xL, zL = 0.0, L
    for _ in range(1000):
        # One sweep of the midpoint rule in plain floats (the sweep is sequential).
        th, x, z = 0.0, 0.0, 0.0
        xs, zs = [0.0], [0.0]
        for j in range(n):
            # midpoint: curvature at j from the current guess of p(L)
            k1 = (Mt[j] + (zL - z) * Fx - (xL - x) * Fz) / EI
            thm = th + 0.5 * ds * k1
            xm = x + 0.5 * ds * math.sin(th)
            zm = z + 0.5 * ds * math.cos(th)
            th += ds * (Mt[j] + (zL - zm) * Fx - (xL - xm) * Fz) / EI
            x += ds * math.sin(thm)
            z += ds * math.cos(thm)
            xs.append(x)
            zs.append(z)
        if math.hypot(x - xL, z - zL) < 1e-4:
            return np.array([x, z]), np.column_stack([xs, zs])
        # relaxed: a large tip load overshoots the plain iteration
        xL, zL = 0.7 * xL + 0.3 * x, 0.7 * zL + 0.3 * z
    raise RuntimeError("rod fixed point did not converge")


def cc_tip_from(th, lengths):
    """Tip (x, z) of constant-curvature arcs with bends th (planar, rad)."""
    x = z = 0.0
    a = 0.0
    for t, ell in zip(th, lengths, strict=True):
        if abs(t) < 1e-9:
            dx, dz = 0.0, ell
        else:
            dx, dz = ell / t * (1 - math.cos(t)), ell / t * math.sin(t)
        x += math.cos(a) * dx + math.sin(a) * dz
        z += -math.sin(a) * dx + math.cos(a) * dz
        a += t
    return np.array([x, z])


def cc_tip(lengths, EI, M_seg, F):
    Mi = [sum(M_seg[j:]) for j in range(len(lengths))]  # tendons crossing segment i

    def energy(th):
        U = sum(EI * t * t / (2 * ell) - M * t for t, ell, M in zip(th, lengths, Mi, strict=True))
        return U - float(np.dot(F, cc_tip_from(th, lengths)))

    th0 = [M * ell / EI for M, ell in zip(Mi, lengths, strict=True)]
    r = minimize(energy, th0, method="BFGS", options={"gtol": 1e-10})
    return cc_tip_from(r.x, lengths)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=float, nargs="+", default=[200.0, 200.0])
    ap.add_argument("--ei", type=float, default=2945.0, help="backbone EI, N mm^2")
    ap.add_argument("--bend-deg", type=float, default=45.0, help="unloaded bend per segment")
    a = ap.parse_args()
    lengths = a.segments
    L = sum(lengths)
    b = math.radians(a.bend_deg)
    # unloaded: EI th_i / l_i = sum of the moments of the tendons crossing segment i
    Mi = [a.ei * b / ell for ell in lengths]
    M_seg = [Mi[j] - (Mi[j + 1] if j + 1 < len(Mi) else 0.0) for j in range(len(Mi))]
    print(
        f"{len(lengths)} segments {lengths} mm, EI {a.ei:g} N mm^2, unloaded bend "
        f"{a.bend_deg:g} deg each; tip distance rod vs cc (mm, % of length {L:g} mm)"
    )
    print(f"{'tip load':28s} {'rod tip x,z':>18s} {'cc tip x,z':>18s} {'gap mm':>7s} {'%L':>6s}")
    for label, F in (
        [("none", (0.0, 0.0))]
        + [
            (f"{f * 1000 / 9.81:.0f} g weight (-z, {f:.2f} N)", (0.0, -f))
            for f in (0.02, 0.05, 0.1)
        ]
        + [(f"sideways +x {f:.2f} N", (f, 0.0)) for f in (0.02, 0.05, 0.1)]
    ):
        Fv = np.array(F)
        pr, _ = rod_tip(lengths, a.ei, M_seg, Fv)
        pc = cc_tip(lengths, a.ei, M_seg, Fv)
        d = float(np.linalg.norm(pr - pc))
        print(
            f"{label:28s} {pr[0]:8.2f},{pr[1]:8.2f} {pc[0]:8.2f},{pc[1]:8.2f} {d:7.2f} "
            f"{100 * d / L:6.2f}"
        )


if __name__ == "__main__":
    main()
