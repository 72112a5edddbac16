"""``python -m cdcr_ctl.sim.loadcells``: the simulated transmitters as their own process."""

import sys

from cdcr_ctl.sim.loadcells.process import main

if __name__ == "__main__":
    sys.exit(main())
