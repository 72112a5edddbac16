#!/usr/bin/env python3
"""The model loop closed through the daemon: run, name, apply, re-run, measured.

For each simulated world with a hidden effect (simulator YAMLs, default every one of
``config/sim/effects/`` but ``none``), with the product's own commands:

1. run: ``cdcr-ctl -c CONTROLLER sim WORLD --lockstep`` starts the production daemon (control
   socket, supervisor, loop, drive layer over CANopen, Modbus load-cell reader, NatNet tracker
   parser, run-log writer) on the lock-step simulated rig (simulated time, as fast as the CPU
   allows; its socket and run logs in private directories); ``cdcr-ctl enable``, ``home`` and
   ``cdcr-ctl trajectory FILE`` over its socket follow the trajectory with the controller's
   config: the world's rig config, with the model switch of a switchable hidden effect off
   (``control.model_effects.<switch>: false``, :data:`SWITCH_OF`); ``cdcr-ctl shutdown``;
2. ``cdcr-ctl discrepancy RUN --apply OVERLAY``: name the effect, write its fitted values as a
   rig-config overlay (the keys the controller's model reads);
3. the controller's config gets the overlay through its ``overlays:`` list (a config that
   extends the first one, as an operator would edit it), the daemon is started again with it
   and the same trajectory file runs again in the same world (same seed);
4. ``cdcr-ctl discrepancy`` on the re-run: its baseline is the controller's model as it now is.

Printed per world: the effect named, the measured tip RMS gap between the controller's model
and the tracker (mm; the tension RMS gap in N on a rig without a tracker) of the first run and
of the re-run, the shrink, and the mean tip error of the commanded pose (mm;
:func:`cdcr_ctl.analysis.tip_errors`) in both runs. Every command's output goes to the world's
directory (``daemon-before.log``, ``cli.log``, ...). Usage::

    .venv/bin/python scripts/discrepancy_loop_demo.py --out /tmp/loop [SIM.yaml ...]
        [--duration-s 25 --seed 11 --trajectory rich --rate-hz 250 --jobs 1]

An overlay whose compensation would step a cable across its friction dead zone faster than
``limits.cable_velocity_mm_s`` at a reversal (the supervisor halts such a run) is run with the
narrowest ``control.reversal_band_mm`` of :data:`REVERSAL_BANDS_MM` that keeps it within the
limit, in both runs (the first made again), said on standard error and on the world's line.

``--jobs N`` runs N worlds side by side (each world's daemon on a socket and in a directory of
its own; lock-step time is simulated, so the figures do not depend on it, only the wall time).
``--trajectory circle --duration-s 0`` is one planar go-and-return to the full bend (no turn).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import contextlib
import json
import math
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from make_discrepancy_runs import (  # noqa: E402
    SWITCH_OF,
    compensation_mode,
    trajectory_within_limits,
)

from cdcr_ctl.analysis import tip_errors  # noqa: E402
from cdcr_ctl.cli.demo import running, wait_for_socket  # noqa: E402
from cdcr_ctl.config import load_rig_config  # noqa: E402
from cdcr_ctl.config.build_model import build_model  # noqa: E402
from cdcr_ctl.errors import RigError  # noqa: E402

EFFECTS_DIR = ROOT / "config" / "sim" / "effects"
#: Acceptance: the gap after applying the overlay is at most 30 % of the gap before.
MIN_SHRINK = 0.70
#: The candidates that name a world's hidden effect right where it is not (only) the world's
#: own name: friction of another law (cdcr_ctl.sim.friction_law) is named ``friction_law`` (its
#: law, applied as ``robot.friction_law``) or, over a motion that cannot tell the laws apart, the
#: model's own disk friction with a corrected coefficient.
NAMED_AS = {"friction_law": ("friction_law", "disk_friction")}
#: A run a cable went slack in even uncompensated is made again bent this much less, down to
#: :data:`MIN_BEND_RAD` (rad).
SLACK_BEND_FACTOR = 0.75
MIN_BEND_RAD = 0.3
#: Friction reversal bands (``control.reversal_band_mm``, mm of material travel) tried, widest
#: last, when an overlay's compensation would step a cable across its friction dead zone faster
#: than ``limits.cable_velocity_mm_s`` at a reversal (the supervisor halts such a run).
REVERSAL_BANDS_MM = (0.02, 0.05, 0.1, 0.2, 0.5, 1.0)
#: Longest wall time a command may take per simulated second of its run, plus a minute (s/s).
WALL_PER_SIM_S = 30.0


def cli_command() -> list[str]:
    """``cdcr-ctl`` as installed beside this interpreter (the console script of the venv), else
    ``python -m cdcr_ctl``."""
    exe = Path(sys.executable).parent / "cdcr-ctl"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "cdcr_ctl"]


def cdcr(log: Path, *args: str, timeout_s: float = 600.0, check: bool = True):
    """Run ``cdcr-ctl ARGS``; its standard output (standard error appended to ``log``).
    ``check``: a non-zero exit raises :class:`SystemExit` naming the command and the log."""
    cmd = [*cli_command(), *args]
    with log.open("a") as err:
        err.write(f"$ cdcr-ctl {' '.join(args)}\n")
        err.flush()
        t0 = time.monotonic()
        p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=err, text=True, timeout=timeout_s)
        err.write(f"# exit {p.returncode} after {time.monotonic() - t0:.1f} s\n")
    if check and p.returncode != 0:
        raise SystemExit(f"cdcr-ctl {' '.join(args)} exited {p.returncode}; see {log}")
    return p


def discrepancy(run: Path, log: Path, *extra: str) -> dict:
    """``cdcr-ctl --json discrepancy RUN ...``: its JSON result (also written to the run)."""
    p = cdcr(log, "--json", "discrepancy", "--no-progress", "--no-plots", str(run), *extra)
    (run / "discrepancy.json").write_text(p.stdout)
    return json.loads(p.stdout)


def controller_config(
    sim: Path, out: Path, rate_hz: float, sock: Path, reversal_band_mm: float | None = None
) -> Path:
    """The first run's controller config: the world's rig config, the hidden effect's model
    switch off, the world's cable geometry, the loop (and SYNC) at ``rate_hz``, the daemon's
    socket ``sock`` and its run logs in ``out/runs``; ``reversal_band_mm``: the friction
    reversal band (None: the rig config's)."""
    doc = yaml.safe_load(sim.read_text())
    rig = (sim.parent / doc["rig"]).resolve()
    geometry = (doc.get("effects") or {}).get("geometry", "chord")
    control: dict = {"geometry": geometry, "rate_hz": rate_hz}
    if reversal_band_mm is not None:
        control["reversal_band_mm"] = reversal_band_mm
    if sim.stem in SWITCH_OF:
        control["model_effects"] = {SWITCH_OF[sim.stem]: False}
    path = out / "controller.yaml"
    doc = {
        "extends": str(rig),
        "control": control,
        "can": {"sync_period_s": 1.0 / rate_hz},
        "daemon": {"socket_path": str(sock)},
        "logging": {"directory": str(out / "runs")},
    }
    path.write_text(yaml.safe_dump(doc))
    return path


def band_within_limits(cfg, traj, rate_hz: float) -> float | None:
    """The narrowest of :data:`REVERSAL_BANDS_MM` wider than ``cfg``'s reversal band with which
    ``cfg``'s compensation keeps every cable within its velocity limit along ``traj``; None if
    none does."""
    for band in REVERSAL_BANDS_MM:
        if band <= cfg.control.reversal_band_mm:
            continue
        model = build_model(cfg, reversal_band_mm=band)
        if compensation_mode(cfg, model, traj, rate_hz, None)[0] != "off":
            return band
    return None


class Tripped(RuntimeError):
    """A run the supervisor ended (its reason)."""


@contextlib.contextmanager
def daemon(sim: Path, ctl: Path, sock: Path, log: Path) -> Iterator[None]:
    """``cdcr-ctl -c CTL sim SIM --lockstep`` (the daemon on the lock-step rig) serving on
    ``sock``, enabled and homed with ``cdcr-ctl enable`` and ``home``; ``cdcr-ctl shutdown`` on
    exit (SIGTERM if it does not stop)."""
    cmd = [*cli_command(), "-c", str(ctl), "sim", str(sim), "--lockstep"]
    with running(cmd, log, ready='"ready"') as proc:
        wait_for_socket(sock, proc, log)
        cli_log = log.with_name("cli.log")
        cdcr(cli_log, "--socket", str(sock), "enable")
        cdcr(cli_log, "--socket", str(sock), "home")
        try:
            yield
        finally:
            with contextlib.suppress(Exception):
                cdcr(cli_log, "--socket", str(sock), "shutdown", timeout_s=30.0, check=False)
                proc.wait(30.0)


def run_once(
    sim: Path, ctl: Path, sock: Path, traj: Path, duration_s: float, name: str, comp: str, out: Path
) -> Path:
    """One run of trajectory file ``traj`` (``duration_s`` long) through the daemon of
    controller config ``ctl``, compensation ``comp``; its run directory. Raises
    :class:`Tripped` when the supervisor ended it."""
    timeout = 60.0 + WALL_PER_SIM_S * duration_s
    for attempt in (1, 2):
        with contextlib.ExitStack() as stack:
            try:
                stack.enter_context(daemon(sim, ctl, sock, out / f"daemon-{name}.log"))
            except RigError as e:
                # The lock-step truth worker's first solve is given SOLVE_TIMEOUT_S of wall
                # time: a machine loaded far beyond its cores can starve it ("did not start").
                # Said, and started once more.
                if attempt == 1 and "did not start" in str(e):
                    print(f"{sim.stem}: {e}; again", file=sys.stderr)
                    continue
                raise SystemExit(str(e)) from None
            p = cdcr(
                out / "cli.log",
                "--json",
                "--socket",
                str(sock),
                "trajectory",
                str(traj),
                "--compensation",
                comp,
                "--name",
                f"{sim.stem}-{name}",
                timeout_s=timeout,
                check=False,
            )
        try:
            res = json.loads(p.stdout)
        except json.JSONDecodeError:
            raise SystemExit(f"cdcr-ctl trajectory exited {p.returncode}: see {out}") from None
        if res.get("state") == "completed":
            return Path(res["log_dir"])
        reason = str(res.get("end_reason"))
        # The drives' heartbeat is watched on the wall clock: on a machine loaded far beyond
        # its cores a starved simulated drive can miss it. Said, and run once more.
        if attempt == 1 and "heartbeat" in reason:
            print(f"{sim.stem}: run ended {res.get('state')} ({reason}); again", file=sys.stderr)
            continue
        raise Tripped(f"{sim}: run {name} ended {res.get('state')}: {reason}")
    raise AssertionError("unreachable")


def loop(
    sim: Path,
    out: Path,
    duration_s: float,
    kind: str,
    seed: int,
    rate_hz: float,
    analysis: tuple[str, ...] = (),
    compensation: str | None = None,
    max_bend_rad: float | None = None,
) -> dict:
    """Run, name, apply, re-run for one world through the daemon; the measured figures.
    ``analysis``: further options of ``cdcr-ctl discrepancy`` (e.g. ``--effects``,
    ``--max-points``); ``compensation``: the loop's mode of both runs (None: the rig config's
    unless the supervisor would halt it, :func:`compensation_mode`); ``max_bend_rad``: a bend
    below the one chosen within the rig's limits (:func:`trajectory_within_limits`)."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    # A Unix socket path holds at most 107 bytes: a private directory of its own, short.
    private = Path(tempfile.mkdtemp(prefix="cdcr-loop-"))
    sock = private / "control.sock"
    try:
        ctl = controller_config(sim, out, rate_hz, sock)
        cfg = load_rig_config(ctl)
        model = build_model(cfg)
        tr, bend, _ = trajectory_within_limits(cfg, model, kind, duration_s, None, seed)
        if max_bend_rad is not None and max_bend_rad < bend:
            tr, bend, _ = trajectory_within_limits(cfg, model, kind, duration_s, max_bend_rad, seed)
        comp, _ = compensation_mode(cfg, model, tr, rate_hz, compensation)
        traj = tr.write(out / f"{kind}.csv")
        while True:
            try:
                run1 = run_once(sim, ctl, sock, traj, tr.duration_s, "before", comp, out)
                break
            except Tripped as e:
                # the controller without the effect let a cable go slack (the supervisor's
                # tension limit; the three-segment coupling world under the uncoupled model's
                # compensation): the lab logs that experiment uncompensated, and the re-run
                # likewise; slack uncompensated too (the world's cables stretch where the
                # config's do not): bent less, SLACK_BEND_FACTOR at a time
                if "tension_low" not in str(e) or bend < MIN_BEND_RAD:
                    raise SystemExit(f"{e} (bend {bend:.3f} rad)") from None
                if comp != "off":
                    comp = "off"
                    print(f"{sim.stem}: {e}; again with compensation off", file=sys.stderr)
                    continue
                bend *= SLACK_BEND_FACTOR
                tr, bend, _ = trajectory_within_limits(cfg, model, kind, duration_s, bend, seed)
                traj = tr.write(out / f"{kind}.csv")
                print(f"{sim.stem}: {e}; again bent to {bend:.3f} rad", file=sys.stderr)
        overlay = out / "overlay.yaml"
        r1 = discrepancy(run1, out / "cli.log", "--apply", str(overlay), *analysis)
        ctl2 = out / "controller-with-overlay.yaml"
        ctl2.write_text(yaml.safe_dump({"extends": str(ctl), "overlays": [str(overlay)]}))
        cfg2 = load_rig_config(ctl2)
        comp2, _ = compensation_mode(cfg2, build_model(cfg2), tr, rate_hz, None)
        band = None
        if comp != "off" and comp2 == "off":
            # the overlay's compensation would step a cable faster than the velocity limit
            # (a fitted friction steps the dead zone at a reversal), which the supervisor
            # halts: both runs are made with a friction reversal band wide enough (the first
            # again), else uncompensated
            band = band_within_limits(cfg2, tr, rate_hz)
            if band is None:
                comp = "off"
                how = "both runs uncompensated"
            else:
                ctl = controller_config(sim, out, rate_hz, sock, band)
                how = f"both runs with control.reversal_band_mm {band:g}"
            print(
                f"{sim.stem}: the overlay's compensation exceeds the velocity limit; {how}",
                file=sys.stderr,
            )
            run1 = run_once(sim, ctl, sock, traj, tr.duration_s, "before", comp, out)
            r1 = discrepancy(run1, out / "cli.log", "--apply", str(overlay), *analysis)
            cfg2 = load_rig_config(ctl2)
            if (
                comp != "off"
                and compensation_mode(cfg2, build_model(cfg2), tr, rate_hz, None)[0] == "off"
            ):
                raise SystemExit(f"{sim}: the refitted overlay's compensation exceeds the limit")
        try:
            run2 = run_once(sim, ctl2, sock, traj, tr.duration_s, "after", comp, out)
        except Tripped as e:
            raise SystemExit(str(e)) from None
        r2 = discrepancy(run2, out / "cli.log", *analysis)
    finally:
        shutil.rmtree(private, ignore_errors=True)
    before, after = r1["tip_rms_before_mm"], r2["tip_rms_before_mm"]
    unit = "mm"
    if not (before == before and after == after):  # no tracker in this rig: the tension gap
        before, after = r1["tension_rms_N"][0][0], r2["tension_rms_N"][0][0]
        unit = "N"
    return {
        "world": sim.stem,
        "named": r1["effect"],
        "verdict": r1["verdict"],
        "gap_before": before,
        "gap_after": after,
        "gap_unit": unit,
        "shrink": 1.0 - after / before,
        "rerun_verdict": r2["verdict"],
        "tip_error_before_mm": _mean_tip_error(run1),
        "tip_error_after_mm": _mean_tip_error(run2),
        "compensation": comp,
        "reversal_band_mm": load_rig_config(ctl).control.reversal_band_mm,
        "band_widened": band is not None,
        "trajectory_s": tr.duration_s,
        "bend_deg": math.degrees(bend),
        "wall_s": time.monotonic() - t0,
        "overlay": str(overlay),
        "runs": [str(run1), str(run2)],
    }


def _mean_tip_error(run: Path) -> float:
    """Mean tip error of the commanded pose (mm); NaN for a rig without a tracker."""
    try:
        return tip_errors(run).summary()["mean_mm"]
    except RigError:
        return math.nan


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sims", type=Path, nargs="*", help="simulator YAMLs [default: the effects]")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--duration-s", type=float, default=25.0)
    ap.add_argument("--trajectory", default="rich", choices=("rich", "random", "circle"))
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument(
        "--rate-hz", type=float, default=250.0, help="loop and SYNC rate of the controller [250]"
    )
    ap.add_argument("--jobs", type=int, default=1, help="worlds side by side [1]")
    ap.add_argument(
        "--max-bend-deg", type=float, default=None, help="cap of the bend [the rig's limits]"
    )
    args = ap.parse_args(argv)
    sims = [p.resolve() for p in args.sims] or sorted(
        p for p in EFFECTS_DIR.glob("*.yaml") if p.stem != "none"
    )
    out = args.out.resolve()
    print(
        f"{'world':18s} {'named':18s} {'gap before':>11s} {'after':>6s} {'shrink':>7s}"
        f"  {'tip err before':>14s} {'after':>6s}  re-run verdict"
    )

    def one(sim: Path) -> dict:
        try:
            r = loop(
                sim,
                out / sim.stem,
                args.duration_s,
                args.trajectory,
                args.seed,
                args.rate_hz,
                max_bend_rad=None if args.max_bend_deg is None else math.radians(args.max_bend_deg),
            )
        except (SystemExit, Exception) as e:
            # one world's failure is said and counted; the others still run
            print(f"{sim.stem:18s} FAILED: {e}", flush=True)
            return {"world": sim.stem, "named": None, "shrink": math.nan, "error": str(e)}
        note = ", uncompensated" if r["compensation"] == "off" else ""
        if r["band_widened"]:
            note += f", reversal band {r['reversal_band_mm']:g} mm"
        print(
            f"{r['world']:18s} {r['named']!s:18s} {r['gap_before']:8.3f} {r['gap_unit']:2s}"
            f" {r['gap_after']:6.3f} {100 * r['shrink']:6.1f}%  {r['tip_error_before_mm']:14.3f}"
            f" {r['tip_error_after_mm']:6.3f}  {r['rerun_verdict']}  ({r['wall_s']:.0f} s"
            f"{note})",
            flush=True,
        )
        return r

    t0 = time.monotonic()
    with concurrent.futures.ThreadPoolExecutor(max(1, args.jobs)) as pool:
        rows = list(pool.map(one, sims))
    (out / "loop.json").write_text(json.dumps(rows, indent=1))
    ok = [
        r
        for r in rows
        if r["named"] in NAMED_AS.get(r["world"], (r["world"],)) and r["shrink"] >= MIN_SHRINK
    ]
    sim_s = "/".join(sorted({f"{r['trajectory_s']:.1f}" for r in rows if "trajectory_s" in r}))
    bends = "/".join(sorted({f"{r['bend_deg']:.0f}" for r in rows if "bend_deg" in r}))
    print(
        f"named right with >= {100 * MIN_SHRINK:.0f} % shrink: {len(ok)} of {len(rows)}"
        f" ({args.trajectory} trajectory, --duration-s {args.duration_s:g}: {sim_s} s simulated"
        f" per run, bend {bends} deg, loop at {args.rate_hz:g} Hz, seed {args.seed};"
        f" {time.monotonic() - t0:.0f} s wall, {args.jobs} at a time)"
    )
    return 0 if len(ok) == len(rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
