"""An independent world for tip-only keypoint logs: a chain of rigid vertebrae on torsional springs.

The controller's model (:mod:`cdcr_ctl.model`) is constant curvature per segment with capstan
friction in the holes. A log made by that same model proves nothing about a real robot, so this
world is written from other physics and shares no code with the model (it reads only the
nominal numbers of a :class:`~cdcr_ctl.model.cc_disk.params.RobotParams`: lengths, hole angles and
radii, EI, EA, pretension, masses):

* **Backbone**: each segment is cut into ``links`` equal pieces of length l with a two-axis
  joint at the middle of each (rotation R_j = Rx(a_j) Ry(b_j) relative to the previous link;
  the pseudo-rigid-body placement, tip error O(1/n^2) against a uniform rod, where joints at
  the pieces' ends would be O(1/n)). The joint stiffness is the rod's k_j = EI(s_j) / l
  (N mm/rad), where EI(s) = f_EI EI_nominal (1 + g (1/2 - s/L)) may
  vary along the segment (``ei_gradient`` g: a backbone stiffer at its base bends more at its
  tip: curvature that is not constant).
* **Tendons**: tendon k runs through a hole in every link up to the tip of its segment; across
  joint j it spans from the hole of link j-1 (at -gap/2 below the joint) to the hole of link j
  (at +gap/2 above it), so its length across the joint depends on (a_j, b_j) only:
  l_kj = | Rx Ry (h_kj + g/2 e_z) - (h_k,j-1 - g/2 e_z) | (frame of link j-1). Holes may sit
  off their nominal radius and angle (``routing_offset``: per tendon, plus a per-hole jitter).
* **Friction along the length**: the tension a tendon applies at joint j is
  T_k exp(-d_k mu_s beta n_kj), with n_kj the holes between the actuator and joint j, beta the
  wrap per hole and d_k = +1 while the tendon is being pulled in, -1 while it is paid out
  (its last actuator move): tension decays towards the tip when pulling and grows when
  releasing. The friction is per segment (``mu``), so every segment has its own hysteresis
  loop; a per-segment lost motion (``play_mm``, a play operator on the actuator position)
  adds a dead zone at reversals.
* **Statics**: the pose minimises E(x) = sum_j k_j (a_j^2 + b_j^2) / 2
  + sum_k k_t,k max(0, e_k)^2 / 2 - sum_i m_i g . c_i with e_k = sum_j w_kj (l_kj(x) - l_kj(0))
  + q_k + T0_k / k_t,k, w_kj the friction weights above (the tension at joint j is then
  k_t e_k w_kj, the capstan-weighted virtual work), k_t = EA / (path + free length). The
  gradient is analytic (joint axes: dl/da_j = u . (R_{j-1} e_x x r), dl/db_j with the axis
  R_{j-1} Rx e_y); scipy's L-BFGS-B minimises it from the previous row's pose.
* **Gravity**: every link carries ``link_mass_g`` at its middle, the tip ``tip_mass_g``: the
  whole arm sags along the nominal robot's gravity vector (``gravity_mm_s2``, base frame: an
  upright, hanging or sideways mount).
* **Tracker**: p_logged = R_reg p_tip + t_reg + noise (``registration``: a base/registration
  error; ``tip_noise_mm`` per axis, at least 1 mm in the hard worlds).

:func:`lab_path` is a lab's calibration set: single-tendon pulls, then combined pulls out and
back between random poses (:func:`cdcr_ctl.sim.keypoint_log.sweep_poses`) sent through the
config's nominal inverse kinematics, as a lab sends them: the model sets the *commands* only,
never the world's response. Its largest bend per segment is the world's
``path_bend_max_rad``. Production code never imports this module.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.optimize import minimize

from cdcr_ctl.model.cc_disk.params import RobotParams
from cdcr_ctl.model.cc_disk.routing import cable_displacement
from cdcr_ctl.sim.keypoint_log import sweep_poses

Q_RESOLUTION_MM = 1.0 / 1238.6


@dataclass(frozen=True)
class WorldSpec:
    """How the world departs from the nominal robot (module docstring); all off by default."""

    links: int = 6  # rigid links per segment
    gap_mm: float = 2.0  # hole spacing across a joint
    ei_factor: tuple[float, ...] = ()  # per segment (default 1)
    ei_gradient: float = 0.0  # g of EI(s) = EI (1 + g (1/2 - s/L))
    ea_factor: float = 1.0
    pretension_factor: float = 1.0
    mu: tuple[float, ...] = ()  # friction per segment (default 0)
    wrap_rad: float = (
        0.04  # beta: wrap per hole (2.3 deg: a tendon path with a small kink at each hole)
    )
    play_mm: tuple[float, ...] = ()  # lost motion per segment (default 0)
    radius_offset_mm: tuple[float, ...] = ()  # per tendon
    angle_offset_rad: tuple[float, ...] = ()  # per tendon
    hole_jitter_mm: float = 0.0  # per hole, random (seeded)
    link_mass_g: float | None = None  # None: nominal disk masses spread over the links
    tip_mass_g: float = 0.0
    registration_rotvec_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    registration_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_noise_mm: float = 1.0
    seed: int = 0
    name: str = "world"
    path_bend_max_rad: float = 0.7  # the largest bend per segment of the world's lab_path
    extra: dict = field(default_factory=dict)


def _rx(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack(
        [np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2
    )


def _ry(b: np.ndarray) -> np.ndarray:
    c, s = np.cos(b), np.sin(b)
    o, z = np.ones_like(b), np.zeros_like(b)
    return np.stack(
        [np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2
    )


def _rotvec(v: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(v))
    if th < 1e-15:
        return np.eye(3)
    k = np.asarray(v) / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


class ChainWorld:
    """The chain of the module docstring for a nominal robot and a :class:`WorldSpec`."""

    def __init__(self, nominal: RobotParams, spec: WorldSpec) -> None:
        self.spec = spec
        rng = np.random.default_rng(spec.seed + 7919)
        S, K, n = nominal.n_segments, nominal.n_cables, spec.links
        self.S, self.K, self.n = S, K, n
        J = S * n
        self.J = J
        self.seg_of_joint = np.repeat(np.arange(S), n)
        l_seg = np.repeat([s.length_mm / n for s in nominal.segments], n)
        # joints at the middle of n equal pieces of each segment: a half piece of straight
        # backbone before the first joint, whole pieces between joints, the two half pieces
        # either side of a segment boundary joined, a half piece after the last joint
        self.base_offset = 0.5 * l_seg[0]
        nxt = np.append(l_seg[1:], 0.0)
        last = (np.arange(J) % n) == n - 1
        self.l_link = np.where(last, 0.5 * l_seg + 0.5 * nxt, l_seg)
        eif = spec.ei_factor or (1.0,) * S
        s_mid = (np.tile(np.arange(n), S) + 0.5) / n  # position of each joint's link along seg
        ei = np.repeat([s.EI_Nmm2 * f for s, f in zip(nominal.segments, eif, strict=True)], n)
        self.k_joint = ei * (1.0 + spec.ei_gradient * (0.5 - s_mid)) / l_seg
        if spec.link_mass_g is None:
            m = np.repeat([s.disk_mass_g * s.n_disks / n for s in nominal.segments], n)
        else:
            m = np.full(J, spec.link_mass_g)
        self.m_kg = m * 1e-3
        self.tip_kg = spec.tip_mass_g * 1e-3
        # holes: (K, J+1, 3) in each link's frame at the link's base (index 0 = base disk)
        r0 = np.array([c.routing_radius_mm for c in nominal.cables])
        g0 = np.array([c.hole_angle_rad for c in nominal.cables])
        dr = np.asarray(spec.radius_offset_mm or (0.0,) * K)
        dg = np.asarray(spec.angle_offset_rad or (0.0,) * K)
        r = (r0 + dr)[:, None] + spec.hole_jitter_mm * rng.normal(size=(K, J + 1))
        g = (g0 + dg)[:, None] + spec.hole_jitter_mm * rng.normal(size=(K, J + 1)) / r0[:, None]
        self.holes = np.stack([r * np.cos(g), r * np.sin(g), np.zeros_like(r)], -1)
        self.last_joint = np.array([(c.segment + 1) * n - 1 for c in nominal.cables])
        self.active = np.arange(J)[None, :] <= self.last_joint[:, None]  # (K, J)
        self.n_holes = np.cumsum(np.ones((K, J)), axis=1)  # holes from the actuator to joint j
        mu = np.asarray(spec.mu or (0.0,) * S)
        self.mu_k = np.array([mu[c.segment] for c in nominal.cables])
        play = np.asarray(spec.play_mm or (0.0,) * S)
        self.play_k = np.array([play[c.segment] for c in nominal.cables])
        ea = np.array([c.EA_N for c in nominal.cables]) * spec.ea_factor
        path = np.array([nominal.segments[: c.segment + 1] for c in nominal.cables], dtype=object)
        L = np.array([sum(s.length_mm for s in p) for p in path]) + np.array(
            [c.free_length_mm for c in nominal.cables]
        )
        self.k_t = ea / L
        self.T0 = np.array([c.pretension_N for c in nominal.cables]) * spec.pretension_factor
        half = 0.5 * spec.gap_mm
        self._v = np.moveaxis(self.holes[:, 1:, :] + np.array([0.0, 0.0, half]), -1, 0)
        self._w = np.moveaxis(self.holes[:, :-1, :] - np.array([0.0, 0.0, half]), -1, 0)
        g = np.asarray(nominal.gravity_mm_s2, float)  # the mount: gravity in the base frame
        self._F = self.m_kg[:, None] * g * 1e-3  # N: kg * mm/s^2 = 1e-3 N
        self._F_tip = self.tip_kg * g * 1e-3
        self._gravity = bool(self.m_kg.any() or self.tip_kg)
        self.l0 = self._crossings(np.zeros(2 * J))[0]
        self.R_reg = _rotvec(np.asarray(spec.registration_rotvec_rad, float))
        self.t_reg = np.asarray(spec.registration_mm, float)
        # memory: pose, direction of each tendon, the play operator's output
        self.x = np.zeros(2 * J)
        self.d = np.ones(K)
        self.q_cable = np.zeros(K)
        self.q_last = np.zeros(K)

    # --- geometry -------------------------------------------------------------------------
    def _crossings(self, x: np.ndarray):
        """Lengths (K, J) of every tendon across every joint, and their gradients (K, J, 2)."""
        a, b = x[0::2], x[1::2]
        ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
        v0, v1, v2 = self._v  # (K, J) components of the hole above each joint, link j
        # Ry(b) v, then Rx(a) (Ry v) = R v
        y0 = cb * v0 + sb * v2
        y2 = -sb * v0 + cb * v2
        r0, r1, r2 = y0, ca * v1 - sa * y2, sa * v1 + ca * y2
        d0, d1, d2 = r0 - self._w[0], r1 - self._w[1], r2 - self._w[2]
        ln = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        u0, u1, u2 = d0 / ln, d1 / ln, d2 / ln
        # d(R v)/da = e_x x (R v) = (0, -r2, r1)
        g_a = -u1 * r2 + u2 * r1
        # d(R v)/db = Rx (e_y x Ry v) = Rx (y2, 0, -y0)
        g_b = u0 * y2 + u1 * (sa * y0) + u2 * (-ca * y0)
        return ln, g_a, g_b

    def frames(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (J, 3, 3) and origins (J+1, 3) of the links (origin J: the tip)."""
        R = _rx(x[0::2]) @ _ry(x[1::2])
        Rw = np.empty_like(R)
        cur = np.eye(3)
        for j in range(self.J):
            cur = cur @ R[j]
            Rw[j] = cur
        o = np.zeros((self.J + 1, 3))
        np.cumsum(Rw[:, :, 2] * self.l_link[:, None], axis=0, out=o[1:])
        o[:, 2] += self.base_offset
        return Rw, o

    def tip(self, x: np.ndarray) -> np.ndarray:
        return self.frames(x)[1][-1]

    # --- statics ---------------------------------------------------------------------------
    def _weights(self) -> np.ndarray:
        w = np.exp(-self.d[:, None] * self.mu_k[:, None] * self.spec.wrap_rad * self.n_holes)
        return np.where(self.active, w, 0.0)

    def energy(self, x: np.ndarray, q: np.ndarray, wts: np.ndarray) -> tuple[float, np.ndarray]:
        """E(x) and dE/dx for cable displacements ``q`` (K,) mm and friction weights (K, J)."""
        ln, g_a, g_b = self._crossings(x)
        e = np.sum(wts * (ln - self.l0), axis=1) + q + self.T0 / self.k_t
        ep = np.maximum(e, 0.0)
        T = self.k_t * ep
        xa, xb = x[0::2], x[1::2]
        E = 0.5 * float(self.k_joint @ (xa * xa + xb * xb)) + 0.5 * float(T @ ep)
        tw = T[:, None] * wts
        grad = np.empty_like(x)
        grad[0::2] = self.k_joint * xa + np.sum(tw * g_a, 0)
        grad[1::2] = self.k_joint * xb + np.sum(tw * g_b, 0)
        if self._gravity:
            Rw, o = self.frames(x)
            c = 0.5 * (o[:-1] + o[1:])
            F = self._F  # (J, 3) N
            E -= float(np.sum(F * c)) + float(self._F_tip @ o[-1])
            # torque about o_j of the weights distal to joint j: sum (c_i - o_j) x F_i
            tau = self._cum_cross(c, o)
            ax_a = np.empty((self.J, 3))
            ax_a[0] = (1.0, 0.0, 0.0)
            ax_a[1:] = Rw[:-1, :, 0]
            ca, sa = np.cos(xa), np.sin(xa)
            prev1 = np.empty((self.J, 3))
            prev2 = np.empty((self.J, 3))
            prev1[0], prev2[0] = (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
            prev1[1:], prev2[1:] = Rw[:-1, :, 1], Rw[:-1, :, 2]
            ax_b = prev1 * ca[:, None] + prev2 * sa[:, None]  # R_{j-1} Rx(a) e_y
            grad[0::2] -= np.sum(ax_a * tau, 1)
            grad[1::2] -= np.sum(ax_b * tau, 1)
        return E, grad

    def _cum_cross(self, c: np.ndarray, o: np.ndarray) -> np.ndarray:
        """Torque (J, 3) about every joint o_j of the weights distal to it:
        sum_{i>=j} c_i x F_i + o_tip x F_tip - o_j x (sum_{i>=j} F_i + F_tip)."""
        F, Ft = self._F, self._F_tip
        M = np.cumsum(np.cross(c, F)[::-1], axis=0)[::-1] + np.cross(o[-1], Ft)
        Fs = np.cumsum(F[::-1], axis=0)[::-1] + Ft
        return M - np.cross(o[:-1], Fs)

    def step(self, q_act: np.ndarray) -> np.ndarray:
        """Settle at actuator positions ``q_act`` (K,) mm; returns the true tip (base frame)."""
        q_act = np.asarray(q_act, float)
        # per-segment play operator between drive and tendon
        lo, hi = q_act - 0.5 * self.play_k, q_act + 0.5 * self.play_k
        self.q_cable = np.clip(self.q_cable, lo, hi)
        dq = q_act - self.q_last
        moved = np.abs(dq) > 1e-6
        self.d = np.where(moved, np.sign(dq), self.d)
        self.q_last = q_act.copy()
        wts = self._weights()
        res = minimize(
            self.energy,
            self.x,
            args=(self.q_cable, wts),
            jac=True,
            method="L-BFGS-B",
            options={"maxiter": 2000, "gtol": 1e-9, "ftol": 1e-15},
        )
        self.x = res.x
        return self.tip(self.x)

    def observe(self, tip: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What the tracker logs: registration error and noise on the true tip."""
        return self.R_reg @ tip + self.t_reg + rng.normal(0.0, self.spec.tip_noise_mm, 3)


def lab_path(
    params: RobotParams,
    n_rows: int,
    seed: int,
    pull_mm: float = 2.5,
    pull_steps: int = 6,
    bend_max_rad: float = 0.7,
) -> np.ndarray:
    """(n_rows, K) actuator keypoints: every tendon pulled alone 0 -> ``pull_mm`` -> 0, then
    combined pulls out and back between random poses (4-10 steps out, back 30-100 %)."""
    rng = np.random.default_rng(seed)
    K, S = params.n_cables, params.n_segments
    rows: list[np.ndarray] = []
    up = np.linspace(0, pull_mm, pull_steps + 1)[1:]
    for k in range(K):
        for v in np.concatenate([up, up[::-1][1:], [0.0]]):
            q = np.zeros(K)
            q[k] = v
            rows.append(q)
    if n_rows > len(rows):
        # the lab's nominal inverse kinematics (Qi et al. 2023 eq. 4) of out-and-back sweeps
        psi = sweep_poses(S, n_rows - len(rows), rng, bend_max_rad)
        rows += [cable_displacement(p, params) for p in psi]
    return np.asarray(rows[:n_rows])


def make_world_log(
    nominal: RobotParams,
    spec: WorldSpec,
    out_dir: Path,
    n_rows: int,
    name: str = "keypoints",
    period_s: float = 0.5,
    path: np.ndarray | None = None,
) -> Path:
    """Solve the world along :func:`lab_path` and write a keypoint run (``samples.csv``,
    ``run.yaml``: tip only, no commanded pose) under ``out_dir/name``; the spec goes to
    ``name.world.json`` beside it (never read by the fit). ``path``: these actuator rows
    (N, K) mm instead of :func:`lab_path` with bends up to ``spec.path_bend_max_rad``."""
    rng = np.random.default_rng(spec.seed)
    if path is None:
        path = lab_path(nominal, n_rows, spec.seed, bend_max_rad=spec.path_bend_max_rad)
    q = np.asarray(path, float)
    q = np.round(q / Q_RESOLUTION_MM) * Q_RESOLUTION_MM
    world = ChainWorld(nominal, spec)
    run_dir = Path(out_dir) / name
    run_dir.mkdir(parents=True, exist_ok=True)
    N, K = q.shape
    t = np.arange(N) * period_s + rng.uniform(-0.02, 0.02, N)
    t[0] = 0.0
    true_tip = np.array([world.step(qi) for qi in q])
    tips = np.array([world.observe(p, rng) for p in true_tip])
    cols = ["t_s", *(f"cable{k + 1}_q_act_mm" for k in range(K)), "tip_x_mm", "tip_y_mm"]
    cols.append("tip_z_mm")
    with (run_dir / "samples.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for i in range(N):
            w.writerow([f"{t[i]:.4f}", *(f"{v:.5f}" for v in q[i]), *(f"{v:.4f}" for v in tips[i])])
    meta = {
        "format": "cdcr-ctl-runlog/1",
        "name": run_dir.name,
        "source": "cdcr_ctl.sim.keypoint_world (independent chain world, keypoint log)",
        "rows": int(N),
    }
    (run_dir / "run.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    doc = {k: v for k, v in asdict(spec).items() if k != "extra"}
    doc["rows"] = int(N)
    (Path(out_dir) / f"{name}.world.json").write_text(json.dumps(doc, indent=2))
    np.save(Path(out_dir) / f"{name}.true_tip.npy", true_tip)
    return run_dir


def make_world_dwell_log(
    nominal: RobotParams,
    spec: WorldSpec,
    out_dir: Path,
    n_dwells: int,
    name: str = "dwells",
    period_s: float = 0.01,
    dwell_s: float = 0.8,
) -> Path:
    """A ``tip``-kind log of the world: commanded poses (out-and-back sweeps) held for
    ``dwell_s`` each, a row every ``period_s`` with the commanded pose, the drives' positions
    (the nominal inverse kinematics of the pose, as a controller sends them) and the tracked
    tip (the world settled at the pose, a fresh tracker noise per row); no load cells."""
    rng = np.random.default_rng(spec.seed)
    S, K = nominal.n_segments, nominal.n_cables
    psi = sweep_poses(S, n_dwells, rng, 0.7)
    q = np.array([cable_displacement(p, nominal) for p in psi])
    q = np.round(q / Q_RESOLUTION_MM) * Q_RESOLUTION_MM
    world = ChainWorld(nominal, spec)
    per = round(dwell_s / period_s)
    run_dir = Path(out_dir) / name
    run_dir.mkdir(parents=True, exist_ok=True)
    cols = ["t_s"]
    cols += [c for i in range(1, S + 1) for c in (f"seg{i}_theta_cmd_rad", f"seg{i}_phi_cmd_rad")]
    cols += [f"cable{k + 1}_q_{c}_mm" for c in ("nominal", "cmd", "act") for k in range(K)]
    cols += ["tip_x_mm", "tip_y_mm", "tip_z_mm"]
    with (run_dir / "samples.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for d in range(n_dwells):
            tip = world.step(q[d])
            pose = [f"{v:.6f}" for v in psi[d].ravel()]
            for j in range(per):
                obs = world.observe(tip, rng)
                t = (d * per + j) * period_s
                qs = [f"{v:.5f}" for v in q[d]] * 3
                w.writerow([f"{t:.4f}", *pose, *qs, *(f"{v:.4f}" for v in obs)])
    meta = {"format": "cdcr-ctl-runlog/1", "name": name, "rows": n_dwells * per}
    meta["source"] = "cdcr_ctl.sim.keypoint_world (independent chain world, dwell log)"
    (run_dir / "run.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return run_dir


def hard_world(seed: int, n_cables: int = 9) -> WorldSpec:
    """The hardest world of the benchmarks and tests: every departure at once. The config is a
    guess far off the built arm, as a lab's is (EI x0.6-1.5 per segment, EA x0.5, holes drilled
    0.8 +- 0.3 mm inside the nominal radius and turned 4-6 deg per segment +- 2 deg per tendon,
    0.1 mm jitter per hole), and the arm has what the model cannot represent: stiffness 1.35 x
    higher at each segment's base than at its tip (curvature not constant), friction along the
    length per segment (mu 0.2-0.35 over a 2.3 deg kink per hole), play per segment, 1 g links
    and a 3 g tip, a 0.5 mm registration error, 1 mm tracker noise per axis. Segments of 3
    tendons are assumed (the tendons' offsets are listed segment by segment)."""
    rng = np.random.default_rng(seed)
    per_seg = np.radians(np.repeat([6.0, -5.0, 4.0], 3)[:n_cables])
    return WorldSpec(
        ei_factor=(1.5, 0.6, 1.4),
        ei_gradient=0.3,
        ea_factor=0.5,
        mu=(0.3, 0.2, 0.35),
        play_mm=(0.05, 0.1, 0.05),
        radius_offset_mm=tuple(float(v) for v in -0.8 + rng.uniform(-0.3, 0.3, n_cables)),
        angle_offset_rad=tuple(
            float(v) for v in per_seg + np.radians(rng.uniform(-2, 2, n_cables))
        ),
        hole_jitter_mm=0.1,
        link_mass_g=1.0,
        tip_mass_g=3.0,
        registration_mm=(0.4, -0.3, 0.2),
        tip_noise_mm=1.0,
        seed=seed,
        name=f"hard{seed}",
    )


def hidden_effect_worlds(seed: int = 1, noise_mm: float = 1.0) -> dict[str, WorldSpec]:
    """One world per effect ``discrepancy`` searches, the rest as the tip-only test config
    (tests/discrepancy/tip_only_rig.yaml: no friction) says, tracker noise ``noise_mm``:
    the key is the effect's name in :mod:`cdcr_ctl.discrepancy.keypoint_effects`."""
    n = noise_mm
    return {
        "curvature": WorldSpec(ei_gradient=1.6, tip_noise_mm=n, seed=seed, name="curvature"),
        "routing": WorldSpec(
            angle_offset_rad=tuple(float(v) for v in np.radians([6] * 3 + [-5] * 3 + [4] * 3)),
            radius_offset_mm=(-0.6,) * 9,
            tip_noise_mm=n,
            seed=seed,
            name="routing",
        ),
        "hysteresis": WorldSpec(
            play_mm=(0.4, 0.8, 1.2), tip_noise_mm=n, seed=seed, name="hysteresis"
        ),
        "registration": WorldSpec(
            registration_rotvec_rad=(0.03, -0.02, 0.01),
            registration_mm=(3.0, -2.0, 1.5),
            tip_noise_mm=n,
            seed=seed,
            name="registration",
        ),
        # the path a lab runs when the arm's sag is in question: bends towards and away from
        # gravity up to 1.3 rad per segment, where the sag's moment arm (and its sign) changes
        # with the pose; a tracker frame's offset is the same rigid map at every pose
        "gravity": WorldSpec(
            link_mass_g=3.0,
            tip_mass_g=10.0,
            tip_noise_mm=n,
            seed=seed,
            name="gravity",
            path_bend_max_rad=1.3,
        ),
    }


def pull_only_path(params: RobotParams, pull_mm: float = 2.5, steps: int = 6) -> np.ndarray:
    """Tendon pulls only: every tendon alone 0 -> ``pull_mm`` -> 0 (the start of
    :func:`lab_path`), with a row at rest before the first pull."""
    n_pulls = params.n_cables * 2 * steps  # per tendon: steps up, steps - 1 down, back at 0
    return np.vstack([np.zeros(params.n_cables), lab_path(params, n_pulls, 0, pull_mm, steps)])
