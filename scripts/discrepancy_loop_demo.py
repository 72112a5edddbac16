#!/usr/bin/env python3
"""The model loop closed in one command: run, name, apply, re-run, measured before and after.

On a simulated world with a hidden effect (a simulator YAML, e.g.
``config/sim/effects/gravity_direction.yaml``):

1. run the experiment: the controller (the rig config the YAML names) drives the world through
   the trajectory, logged as the loop logs (``scripts/make_discrepancy_runs.py``'s generator);
2. ``cdcr-ctl discrepancy RUN --apply OVERLAY``: name the effect, write its fitted values as a
   rig-config overlay;
3. the controller's config gets the overlay through its ``overlays:`` list (a new controller
   config that extends the old one, as an operator would edit it), and the same experiment
   (same trajectory, same seed) runs again with it;
4. ``cdcr-ctl discrepancy`` on the re-run: its *baseline* (the controller's model as it now is)
   against the world, measured.

Prints the measured tip RMS gap (model vs tracker, mm) of the first run and of the re-run, and
the shrink. Usage::

    .venv/bin/python scripts/discrepancy_loop_demo.py config/sim/effects/gravity_direction.yaml \
        --out /tmp/loop-demo [--duration-s 60 --rate-hz 100 --seed 11]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

from make_discrepancy_runs import make_run  # noqa: E402

from cdcr_ctl.cli.main import main as cdcr_main  # noqa: E402


def discrepancy(run: Path, *extra: str) -> dict:
    """``cdcr-ctl --json discrepancy RUN ...``: its JSON result."""
    out = run / "discrepancy.json"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = cdcr_main(["--json", "discrepancy", "--no-progress", "--no-plots", str(run), *extra])
    text = buf.getvalue()
    out.write_text(text)
    if rc != 0:
        raise SystemExit(f"cdcr-ctl discrepancy {run} exited {rc}:\n{text}")
    return json.loads(text)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sim", type=Path, help="simulator YAML with the hidden effect")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args(argv)
    sim = args.sim.resolve()
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    hidden = sim.stem
    kw = {"hidden": hidden, "duration_s": args.duration_s, "rate_hz": args.rate_hz}

    # 1. the experiment with the controller as configured
    run1 = make_run(sim, out / "before", seed=args.seed, **kw)
    # 2. name the effect and write it as an overlay
    overlay = out / "overlay.yaml"
    r1 = discrepancy(run1, "--apply", str(overlay))
    # 3. the controller's config with the overlay in its overlays list; the same world
    doc = yaml.safe_load(sim.read_text())
    rig = (sim.parent / doc["rig"]).resolve()
    ctl = out / "controller-with-overlay.yaml"
    ctl.write_text(yaml.safe_dump({"extends": str(rig), "overlays": [str(overlay)]}))
    doc["rig"] = str(ctl)
    sim2 = out / sim.name  # same stem: the same hidden effect, now known to the controller
    sim2.write_text(yaml.safe_dump(doc, sort_keys=False))
    run2 = make_run(sim2, out / "after", seed=args.seed, **kw)
    # 4. the re-run, measured against the controller's model as it now is
    r2 = discrepancy(run2)
    before = r1["tip_rms_before_mm"]
    after = r2["tip_rms_before_mm"]
    print(f"hidden effect: {hidden}; named: {r1['effect']} ({r1['verdict']})")
    print(f"overlay: {overlay}")
    print(
        f"measured tip RMS gap, controller's model vs tracker: {before:.3f} mm before, "
        f"{after:.3f} mm after applying it (re-run, same trajectory and seed): shrink "
        f"{100 * (1 - after / before):.1f} %; re-run verdict: {r2['verdict']}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
