"""``python -m cdcr_ctl.sim.epos RIG.yaml [--link PATH]``: the rig's simulated drives behind an
slcan pseudo-terminal, in their own process. Prints the pty path on the first line; runs until
SIGTERM."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.sim.epos.rig import SimDriveBus


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m cdcr_ctl.sim.epos", description=__doc__)
    ap.add_argument("rig", help="rig config (YAML)")
    ap.add_argument("--link", default=None, help="symlink to create to the pty")
    args = ap.parse_args(argv)
    rig = load_rig_config(args.rig)
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    drives = SimDriveBus(rig, "slcan", link=args.link).start()
    print(drives.channel_path, flush=True)
    stop.wait()
    drives.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
