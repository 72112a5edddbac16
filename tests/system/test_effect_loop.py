"""System: run, name, apply, re-run through the daemon as it is typed
(scripts/discrepancy_loop_demo.py, the command the effects page's table comes from):
``cdcr-ctl sim WORLD --lockstep`` serves the production daemon on the lock-step rig, ``cdcr-ctl
enable``, ``home`` and ``trajectory FILE`` drive the run over its socket, ``cdcr-ctl discrepancy
--apply`` writes the overlay, the daemon is started again with the overlay in its config and
the re-run is measured.

A world whose overlay the controller never read before (an actuator scale error: the drives'
counts_per_mm): the effect is named, its overlay goes into the controller's config, and the
re-run's gap between the controller's model and the tracker shrinks by >= 70 %. Lean: one
planar go-and-return to 45 deg (``circle`` trajectory of 0 s: no turn; 4.5 s simulated: the
scale error grows with the cable travel; measured: gap 0.585 mm -> 0.042 mm, 92.8 %, where the
full 90 deg bend gives 1.116 -> 0.038 mm) and two candidates; the whole set of worlds is the
script's default, as the effects page runs it (docs/calibration/effects-and-loads.md):

    .venv/bin/python scripts/discrepancy_loop_demo.py --out effect-loop \
        --trajectory circle --duration-s 0 --jobs 2
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from scriptload import load_script

ROOT = Path(__file__).resolve().parents[2]
EFFECTS = ROOT / "config" / "sim" / "effects"


@pytest.mark.timeout(900)
def test_apply_through_the_daemon_closes_the_gap(tmp_path):
    world = "actuator_scale"
    demo = load_script("discrepancy_loop_demo")
    analysis = (
        "--effects",
        "actuator_scale,backlash",
        "--max-points",
        "150",
        "--jobs",
        "1",
        "--no-pairs",
    )
    # compensation "model" given (the rig config's): no check of the trajectory beforehand
    r = demo.loop(
        EFFECTS / f"{world}.yaml",
        tmp_path,
        0.0,
        "circle",
        11,
        250.0,
        analysis,
        "model",
        max_bend_rad=math.pi / 4,
    )
    assert r["named"] == world, r
    assert r["shrink"] >= demo.MIN_SHRINK, r
    # the controller's config read the overlay: the re-run was commanded differently
    assert r["tip_error_after_mm"] < r["tip_error_before_mm"], r
    # both runs were the daemon's: logged by it, with the config it ran (the overlay's counts
    # per mm in the re-run's), and it was shut down by the CLI both times
    before, after = (Path(p) for p in r["runs"])
    overlay = yaml.safe_load(Path(r["overlay"]).read_text())
    applied = [d["counts_per_mm"] for d in overlay["drives"]]
    ran = yaml.safe_load((after / "config_effective.yaml").read_text())
    assert [d["counts_per_mm"] for d in ran["drives"]] == applied
    first = yaml.safe_load((before / "config_effective.yaml").read_text())
    assert [d["counts_per_mm"] for d in first["drives"]] != applied
    for tag in ("before", "after"):
        log = (tmp_path / f"daemon-{tag}.log").read_text()
        assert "lock-step daemon stopped: shutdown requested" in log, log[-2000:]
