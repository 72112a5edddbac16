"""``python -m cdcr_ctl.sim.tracker``: a simulated NatNet server as its own process."""

from cdcr_ctl.sim.tracker.process import main

if __name__ == "__main__":
    raise SystemExit(main())
