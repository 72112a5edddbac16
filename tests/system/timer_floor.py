"""The machine's timing floor, in a process of its own (issue #21, acceptance 1).

Run: ``python tests/system/timer_floor.py PERIOD_S OUT.npy [REALTIME_PRIORITY]``: prints
``ready``, then runs :func:`cdcr_ctl.control.timing.timer_floor` (the control loop's clock,
sleep and spin, doing nothing) with the loop thread's switch interval and the daemon's
scheduling policy, until SIGTERM or stdin closes; saves each cycle's lateness (us) to OUT.npy.
The battery (``tests/system/battery.py``) runs one during each stressor, so it sees the same load
as the daemon's loop.
"""

from __future__ import annotations

import gc
import signal
import sys
import threading

import numpy as np

from cdcr_ctl.control.loop import GIL_SWITCH_INTERVAL_S
from cdcr_ctl.control.timing import timer_floor, try_realtime

#: At most this long (s) at any rate: the array is allocated up front.
MAX_SECONDS = 600


def main() -> None:
    period_s = float(sys.argv[1])
    out = sys.argv[2]
    priority = int(sys.argv[3]) if len(sys.argv) > 3 else 0
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    # As the daemon: scheduling policy first, the loop thread's switch interval, frozen heap.
    try_realtime(priority, False)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    gc.freeze()
    print("ready", flush=True)
    lateness = timer_floor(period_s, stop.is_set, int(MAX_SECONDS / period_s))
    np.save(out, lateness * 1e6)


if __name__ == "__main__":
    main()
