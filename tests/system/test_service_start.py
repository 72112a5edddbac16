"""System: the systemd unit's ``ExecStart`` line, run as systemd would run it, starts a daemon
that notifies READY, keeps petting the watchdog, logs runs under the unit's state directory,
answers the CLI with its options before or after the command, and ends on SIGTERM with exit 0
within ``TimeoutStopSec``.

What systemd itself would add is set by the test: ``NOTIFY_SOCKET`` (a datagram socket this test
binds and reads), ``WATCHDOG_USEC`` (from ``WatchdogSec=``), ``STATE_DIRECTORY`` and
``RUNTIME_DIRECTORY`` (temporary directories) and the working directory (the state directory,
as ``WorkingDirectory=`` says). The line is the unit's, word for word, with only the installed
binary's path (``/opt/cdcr-ctl/.venv/bin/cdcr-ctl``) and the config path
(``/etc/cdcr-ctl/rig.yaml``) replaced by this checkout's and a simulated rig's.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from syshelp import client, session, start_sim, wait_run_end

from cdcr_ctl.control import trajectory as tj
from cdcr_ctl.ownership import bus_key

pytestmark = [pytest.mark.slow, pytest.mark.realtime, pytest.mark.timeout(240)]

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "systemd" / "cdcr-ctl.service"
INSTALLED_EXE = "/opt/cdcr-ctl/.venv/bin/cdcr-ctl"
INSTALLED_CONFIG = "/etc/cdcr-ctl/rig.yaml"
EXE = Path(sys.executable).parent / "cdcr-ctl"


def unit_setting(name: str) -> str:
    m = re.search(rf"^{name}=(.*)$", UNIT.read_text(), re.M)
    assert m, f"{UNIT}: no {name}="
    return m.group(1).strip()


def exec_start(config: Path) -> list[str]:
    """The unit's ExecStart, split as systemd splits it, with the two paths substituted."""
    argv = shlex.split(unit_setting("ExecStart"))
    assert argv[0] == INSTALLED_EXE and INSTALLED_CONFIG in argv, argv
    return [str(EXE) if a == INSTALLED_EXE else str(config) if a == INSTALLED_CONFIG else a
            for a in argv]  # fmt: skip


class NotifySocket:
    """The service manager's end of sd_notify: every datagram with its arrival time."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.messages: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            self.messages.append((time.monotonic(), data.decode()))

    def times(self, item: str) -> list[float]:
        return [t for t, m in self.messages if item in m.split("\n")]

    def wait_for(self, item: str, timeout_s: float) -> float:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            got = self.times(item)
            if got:
                return got[0]
            time.sleep(0.05)
        raise AssertionError(f"no {item} in {timeout_s} s; got {self.messages[-5:]}")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.sock.close()


def cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``cdcr-ctl ARGS`` as typed, by its installed entry point."""
    return subprocess.run([str(EXE), *args], capture_output=True, text=True, timeout=60, env=env)


def test_exec_start_runs_notifies_logs_under_the_state_directory_and_stops(tmp_path):
    watchdog_s = float(unit_setting("WatchdogSec"))
    stop_timeout_s = float(unit_setting("TimeoutStopSec"))
    state, runtime = tmp_path / "state", tmp_path / "runtime"
    state.mkdir()
    runtime.mkdir(mode=0o750)
    with session(tmp_path) as (work, rig, sim, _runs), start_sim(sim, tmp_path / "sim.log"):
        # The lab's config says nothing about logs: the defaults apply (the state directory).
        doc = yaml.safe_load(rig.read_text())
        del doc["logging"]
        rig.write_text(yaml.safe_dump(doc, sort_keys=False))
        notify = NotifySocket(work / "notify")
        env = {k: v for k, v in os.environ.items() if k != "CDCR_CTL_LOCK_DIR"}
        env.update(
            NOTIFY_SOCKET=str(notify.path),
            WATCHDOG_USEC=str(int(watchdog_s * 1e6)),
            STATE_DIRECTORY=str(state),
            RUNTIME_DIRECTORY=str(runtime),
        )
        log_path = tmp_path / "daemon.log"
        with log_path.open("w") as log:
            t0 = time.monotonic()
            d = subprocess.Popen(
                exec_start(rig), cwd=state, env=env, stdout=log, stderr=log,
                start_new_session=True,
            )  # fmt: skip
        try:
            ready = notify.wait_for("READY=1", 60)
            assert d.poll() is None, log_path.read_text()[-2000:]
            # One daemon per bus and per socket: its locks are in the runtime directory.
            held = sorted(p.read_text().split()[1] for p in runtime.glob("*.lock"))
            assert held == [
                bus_key("slcan", str(work / "can")),
                f"socket:{work / 'control.sock'}",
            ]
            assert all(p.read_text().split()[0] == str(d.pid) for p in runtime.glob("*.lock"))

            # Options where people type them: before and after the command, same answer.
            for args in (
                ("-c", str(rig), "status", "--json"),
                ("status", "-c", str(rig), "--json"),
                ("--json", "-c", str(rig), "status"),
            ):
                res = cli(*args)
                assert res.returncode == 0, (args, res.stderr)
                assert json.loads(res.stdout)["rig"] == "qi2023-sim", args
            res = cli("status", "--config", str(rig))
            assert res.returncode == 0 and res.stdout.splitlines()[0].startswith("qi2023-sim")
            assert len(res.stdout.splitlines()) < 30, res.stdout  # a summary, not every field

            # A run: its log lands under the state directory.
            traj = tj.go_and_return(theta_max_rad=0.3, rate_rad_s=0.3)  # ~2 s
            with client(work) as c:
                c.call("enable")
                res = c.call("trajectory", name="svc", samples=traj.rows(), log=True)
            assert Path(res["log_dir"]).parent == state / "runs"
            with client(work) as c:
                seen_logging = c.call("status")["logging"]
            run, _ = wait_run_end(work, res["run"], 60)
            assert run["state"] == "completed", run
            assert seen_logging is True  # `watch` and `status` say a running run logs
            assert (Path(res["log_dir"]) / "samples.csv").is_file()

            # The watchdog was petted within WatchdogSec/2 from READY to now.
            beats = [ready, *notify.times("WATCHDOG=1"), time.monotonic()]
            gaps = [b - a for a, b in itertools.pairwise(beats)]
            assert len(beats) > 3 and max(gaps) < watchdog_s / 2, gaps

            t_term = time.monotonic()
            d.send_signal(signal.SIGTERM)
            rc = d.wait(stop_timeout_s)
            took = time.monotonic() - t_term
        finally:
            if d.poll() is None:
                d.kill()
                d.wait()
            notify.close()
        out = log_path.read_text()
        assert rc == 0, out[-2000:]
        assert notify.times("STOPPING=1"), notify.messages[-5:]
        # An ordered stop says so, and nothing about a rig process that "did not end".
        assert "did not end" not in out, out[-2000:]
        assert "Connected to 'unknown'" not in out
        print(f"ready {ready - t0:.1f} s after start; SIGTERM to exit {took:.2f} s")
