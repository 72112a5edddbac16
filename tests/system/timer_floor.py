"""The machine's timing floor, in a process of its own (issue #21, acceptance 1).

Run: ``python tests/system/timer_floor.py PERIOD_S OUT.npy [REALTIME_PRIORITY [CPU]]``: prints
``ready``, then runs :func:`cdcr_ctl.control.timing.timer_floor` (the control loop's clock,
sleep and spin, doing nothing) with the loop thread's switch interval and the daemon's
scheduling policy, until SIGTERM or stdin closes; saves each cycle's lateness (us) and
deadline (``time.monotonic``, s) to OUT.npy, one row per cycle. With CPU, the process stays
on that CPU (``sched_setaffinity``). The battery
(``tests/system/battery.py``) runs one on each CPU the daemon may use through each window: the
loop's thread moves between CPUs, and a stall of one CPU (a virtual machine's vCPU held by its
host) delays only what runs there, so only a floor on that CPU sees it, at the same time.
"""

from __future__ import annotations

import gc
import os
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
    if len(sys.argv) > 4:
        os.sched_setaffinity(0, {int(sys.argv[4])})
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    # As the daemon: scheduling policy first, the loop thread's switch interval, frozen heap.
    try_realtime(priority, False)
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    gc.freeze()
    print("ready", flush=True)
    n_max = int(MAX_SECONDS / period_s)
    deadlines = np.empty(n_max)
    lateness = timer_floor(period_s, stop.is_set, n_max, deadlines)
    np.save(out, np.column_stack((lateness * 1e6, deadlines[: len(lateness)])))


if __name__ == "__main__":
    main()
