"""Where the lock-step truth worker ran after each wake-up by the loop's process: on the CPU of
the thread that woke it, or another. Reads ``perf sched record`` data.

    perf sched record -o /tmp/ls.data -- .venv/bin/python benchmarks/bench_lockstep.py --no-parts
    .venv/bin/python benchmarks/lockstep_placement.py /tmp/ls.data LOOP_PID WORKER_PID

(the benchmark prints the two pids). For each ``sched_waking`` of the worker done by a thread of
the loop's process, the CPU of the worker's next ``sched_switch`` in is compared with the
waker's CPU. Needs ``perf`` and the right to trace scheduler events (root, or
``kernel.perf_event_paranoid`` <= -1).
"""

from __future__ import annotations

import re
import subprocess
import sys

LINE = re.compile(r"^\s*(\d+)/(\d+)\s+\[(\d+)\]\s+[\d.]+:\s+sched:(\w+):\s+(.*)$")


def main() -> None:
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    data, loop_pid, worker = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    out = subprocess.run(
        ["perf", "script", "-i", data, "-F", "pid,tid,cpu,time,event,trace"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    waker_cpu = None
    woken = same = 0
    for line in out.splitlines():
        m = LINE.match(line)
        if m is None:
            continue
        pid, cpu, event, trace = int(m[1]), int(m[3]), m[4], m[5]
        if event == "sched_waking" and pid == loop_pid:
            target = re.search(r" pid=(\d+)", trace)
            if target is not None and int(target[1]) == worker:
                waker_cpu = cpu
        elif event == "sched_switch" and waker_cpu is not None:
            nxt = re.search(r"next_pid=(\d+)", trace)
            if nxt is not None and int(nxt[1]) == worker:
                woken += 1
                same += cpu == waker_cpu
                waker_cpu = None
    print(
        f"truth worker {worker}: woken by the loop's process {woken} times; ran next on the "
        f"waker's CPU {same} times ({100 * same / max(woken, 1):.0f} %)"
    )


if __name__ == "__main__":
    main()
