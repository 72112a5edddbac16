"""Run a command at a lower priority in a session of its own: ``in_session.py N CMD...``.

``scripts/test`` runs the rest of the suite this way beside the wall-clock unit (README "CI
time"). With the kernel's autogroups on (``/proc/sys/kernel/sched_autogroup_enabled``; this
machine's default), the CPU is shared between sessions first and a process's nice counts only
inside its session; and a session started below this one (the lock-step rigs the rest's tests
start, each in a session of its own: ``cdcr_ctl.cli.demo.running``) takes its autogroup level
from this session's. So the nice level ``N`` goes to both: this process (inherited by what it
starts) and its new session's autogroup. The command replaces this process (same pid), so the
caller can raise the session's level again later (``/proc/PID/autogroup``). A step that is not
permitted or not there (no autogroups) is skipped.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path


def main(argv: list[str]) -> None:
    if len(argv) < 2:
        sys.exit("usage: in_session.py N CMD [ARG...]")
    nice, cmd = int(argv[0]), argv[1:]
    try:
        os.setsid()
    except OSError as exc:  # already a process group leader: stays in the caller's session
        print(f"in_session.py: no session of its own ({exc}); nice only", file=sys.stderr)
    else:
        with contextlib.suppress(OSError):
            Path("/proc/self/autogroup").write_text(f"{nice}\n")
    os.nice(nice)
    os.execvp(cmd[0], cmd)


if __name__ == "__main__":
    main(sys.argv[1:])
