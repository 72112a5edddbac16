"""The doc runner's hang guard (docrun.run_guarded): a command past its time limit goes on while
it computes and is given up on when it stalls, whatever the machine's load."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
from docrun import run_guarded, session_cpu_s

#: A small limit and window for the test (s); the runner's are 90 s and 30 s.
LIMIT_S = 1.0
WINDOW_S = 1.0
POLL_S = 0.2
#: A computing command uses ~1 s of CPU per second idle, ~0.3 s beside `stress-ng --cpu 2`
#: (a third of a core): 0.05 s per window is far below either and far above a sleeper's 0.
STALL_CPU_S = 0.05


def _burn(cpu_s: float) -> str:
    """Python source that computes for ``cpu_s`` of its own CPU time."""
    return f"import time\ne = time.process_time() + {cpu_s}\nwhile time.process_time() < e: pass"


def _env() -> dict[str, str]:
    return dict(os.environ)


def test_a_computing_command_runs_past_the_limit(tmp_path):
    busy = f"{sys.executable} -c '{_burn(2.5)}'"
    t0 = time.monotonic()
    res = run_guarded(busy, tmp_path, _env(), LIMIT_S, WINDOW_S, STALL_CPU_S, 120.0, POLL_S)
    assert res.returncode == 0, res.stderr
    assert time.monotonic() - t0 > LIMIT_S  # it went on past the limit


def test_a_stalled_command_is_given_up_on_and_its_session_killed(tmp_path):
    pidfile = tmp_path / "pid"
    cmd = f"sleep 60 & echo $! > {pidfile}; wait"
    t0 = time.monotonic()
    with pytest.raises(subprocess.TimeoutExpired) as exc:
        run_guarded(cmd, tmp_path, _env(), LIMIT_S, WINDOW_S, STALL_CPU_S, 120.0, POLL_S)
    took = time.monotonic() - t0
    assert "stalled" in exc.value.output
    # Given up on past the limit, once a whole window without CPU was seen; not at the backstop.
    assert max(LIMIT_S, WINDOW_S) <= took < 30.0
    sleeper = int(pidfile.read_text())
    deadline = time.monotonic() + 5.0
    while os.path.exists(f"/proc/{sleeper}") and time.monotonic() < deadline:
        time.sleep(0.05)  # SIGKILL is delivered, the zombie reaped by init
    assert not os.path.exists(f"/proc/{sleeper}") or "Z" in _state(sleeper)


def test_the_backstop_ends_a_command_that_computes_forever(tmp_path):
    spin = f"{sys.executable} -c 'while True: pass'"
    with pytest.raises(subprocess.TimeoutExpired) as exc:
        run_guarded(spin, tmp_path, _env(), LIMIT_S, WINDOW_S, STALL_CPU_S, 3.0, POLL_S)
    assert "ran over 3 s" in exc.value.output


def test_session_cpu_counts_the_sessions_processes():
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            _burn(0.5) + "\ntime.sleep(30)",
        ],
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 60.0
        while session_cpu_s(proc.pid) < 0.5 and time.monotonic() < deadline:
            time.sleep(0.1)
        # 0.5 s of CPU burnt, counted in clock ticks (1/100 s) plus the interpreter's start.
        assert 0.49 <= session_cpu_s(proc.pid) < 5.0
        assert session_cpu_s(2**22 + 12345) == 0.0  # no such session
    finally:
        proc.kill()
        proc.wait()


def _state(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"
