"""The documentation's commands, as a reader would type them, run against one simulated rig.

Every ```sh block of README.md and docs/**/*.md is read line by line (a line ending in ``\\``
goes on). A block preceded by an HTML comment on its own line is marked:

- ``<!-- cmd: hardware-only: REASON -->``: not run (needs real hardware, root or systemd); the
  reason must be given;
- ``<!-- cmd: background -->``: a long-running process (``cdcr-ctl sim``, ``cdcr-ctl daemon``).
  The simulated rig and the daemon are the shared ones (:class:`DocRig`, started once on free
  ports and private paths and kept until the last page); any other command is started here and
  stopped at the end of its page;
- ``<!-- cmd: covered-by tests/PATH.py::TEST -->``: too slow for this runner; that test runs the
  same command. Checked: the file and the test exist, and the command's words (its subcommand
  and plain arguments, the names of scripts it runs) appear in that file.

Every other line runs in ``bash -o pipefail`` and must exit 0, with ``cdcr-ctl`` (the project's
venv) on ``PATH``, in a scratch directory that shows the repository's files and whose ``runs/``
is the shared daemon's run-log directory. The rig configs of the simulated rig are swapped for
the shared rig's: ``config/qi2023-sim.yaml`` for the session's rig config (its control socket,
its CAN adapter's and load cells' loopback TCP ports, its tracker port), ``config/sim/*.yaml``
in a ``cdcr-ctl sim`` line for the session's simulator config of that world.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
VENV_BIN = ROOT / ".venv" / "bin"
#: The simulated rig's config as the pages name it; swapped for the shared rig's.
SIM_RIG = "config/qi2023-sim.yaml"
#: The world of the shared rig unless a page's ``cdcr-ctl sim`` line names another: the clean
#: world, as the system tests use (the default world's lost motion slackens an uncompensated
#: cable, which the tension limit rightly trips on; the pages exercise the commands).
DEFAULT_WORLD = "config/sim/qi2023-truth-clean.yaml"
MARK = re.compile(r"^<!--\s*cmd:\s*(.*?)\s*-->\s*$")
#: Words that are the shell's or the interpreter's, not the command's (for ``covered-by``).
NOT_WORDS = {"cdcr-ctl", "sudo", "nice", "python", "time", "env", "bin", "venv"}
#: One command's time limit (s, wall clock): the runner's whole budget is about a minute. Past it
#: a command still computing goes on (:func:`run_guarded`): a lock-step script's wall time is its
#: CPU time stretched by the machine's load (7 s idle, over 90 s in the suite beside ``stress-ng
#: --cpu 2``); a hung command computes nothing.
COMMAND_TIMEOUT_S = 90.0
#: Past :data:`COMMAND_TIMEOUT_S`, a command whose processes used less CPU than
#: :data:`STALL_CPU_S` over the last :data:`STALL_WINDOW_S` of wall time is given up on (s).
#: A hung command uses no CPU; a lock-step run computes 7 s in its 23 s beside ``stress-ng --cpu
#: 2`` alone, and starved to a twentieth of a core (the shared rig's real-time threads and the
#: load) still 1.5 s in 30 s. A client polling a daemon that never answers uses a few ms a second
#: and ends on the backstop.
STALL_WINDOW_S = 30.0
STALL_CPU_S = 0.3
#: Any command is given up on after this (s, wall clock), computing or not.
COMMAND_BACKSTOP_S = 360.0
#: Trips that a loaded machine causes on the simulated rig, not the documented command: the
#: stand-in drives' heartbeats and feedback and the stand-in sensors' samples come late when the
#: simulator gets no CPU (the system tests retry a run for the same causes).
#: (An EMCY 0x8130 is a drive that missed the controller's heartbeat.)
LOAD_TRIPS = re.compile(
    r"^(heartbeat:|no_feedback:|stale_tension:|stale_tracker|emcy:node\d+:0x8130)"
)
#: The same causes in a command's own error (an ``enable`` during which a heartbeat was lost).
LOAD_ERRORS = re.compile(r"heartbeat lost|no TPDO from any drive|bus not answering")


@dataclass
class Command:
    line: int  # 1-based line of the page where the command starts
    text: str


@dataclass
class Block:
    line: int  # the opening fence's line
    mark: str  # "", "background", "hardware-only: ...", "covered-by ..."
    commands: list[Command] = field(default_factory=list)


def pages() -> list[Path]:
    """README.md and every Markdown page of the manual, in a fixed order."""
    docs = sorted(p for p in (ROOT / "docs").rglob("*.md") if "_build" not in p.parts)
    return [ROOT / "README.md", *docs]


def blocks(path: Path) -> list[Block]:
    """The ```sh blocks of a page with their marks and commands."""
    lines = path.read_text().splitlines()
    out: list[Block] = []
    i = 0
    while i < len(lines):
        if lines[i].strip() == "```sh":
            prev = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
            m = MARK.match(prev.strip())
            block = Block(i + 1, m.group(1) if m else "")
            i += 1
            pending, start = "", 0
            while i < len(lines) and lines[i].strip() != "```":
                text = lines[i]
                if not pending:
                    start = i + 1
                if text.rstrip().endswith("\\"):
                    pending += text.rstrip()[:-1] + " "
                else:
                    cmd = (pending + text).strip()
                    pending = ""
                    if cmd and not cmd.startswith("#"):
                        block.commands.append(Command(start, cmd))
                i += 1
            out.append(block)
        i += 1
    return out


def command_words(cmd: str) -> list[str]:
    """The words of a command a test running it must contain: plain words (the subcommand and
    its arguments) and the names of the scripts it runs; options, numbers and paths to data
    are not words."""
    words = []
    for tok in shlex.split(cmd, comments=True):
        if tok in {"|", "&&", ";"} or tok.startswith("-") or "=" in tok:
            continue
        if "/" in tok:
            stem = Path(tok).stem
            if Path(tok).parts[0] in {"scripts", "benchmarks"}:
                words.append(stem)
            continue
        if re.fullmatch(r"[a-z][a-z0-9_-]*", tok) and tok not in NOT_WORDS:
            words.append(tok)
    return words


def check_covered_by(mark: str, cmd: str) -> str | None:
    """None when the covering test exists and holds the command's words, else what is wrong."""
    target = mark.removeprefix("covered-by").strip()
    path, _, test = target.partition("::")
    file = ROOT / path
    if not path.startswith("tests/") or not file.is_file():
        return f"covered-by names no test file: {target!r}"
    text = file.read_text()
    if not test or not re.search(rf"def {re.escape(test)}\b", text):
        return f"covered-by: no test {test!r} in {path}"
    missing = [w for w in command_words(cmd) if w not in text]
    if missing:
        return f"covered-by {target}: {path} never mentions {missing} of `{cmd}`"
    return None


class DocRig:
    """One simulated rig and its daemon for every page, on free ports and private paths."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.work = Path(tempfile.mkdtemp(prefix="cdcr-doc-", dir="/tmp"))  # short socket paths
        self.cwd = tmp / "cwd"
        self.cwd.mkdir()
        for entry in ROOT.iterdir():
            if entry.name not in {"runs", ".git"}:
                (self.cwd / entry.name).symlink_to(entry)
        self.runs = self.cwd / "runs"
        self.runs.mkdir()
        self.world: str | None = None
        self.rig: Path | None = None
        self.sim: Path | None = None
        self._stack = contextlib.ExitStack()
        self._daemon = None

    def env(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("CDCR_CTL_")}
        env["PATH"] = f"{VENV_BIN}:{env.get('PATH', '/usr/bin:/bin')}"
        env["MPLBACKEND"] = "Agg"
        return env

    def ensure(self, world: str = DEFAULT_WORLD, daemon: bool = True) -> None:
        """The shared simulator of ``world`` (restarted when a page names another world) and,
        with ``daemon``, the daemon on it."""
        # As the system tests start them (tests/system/syshelp.py): the simulator as stand-in
        # hardware (at SIM_NICE until ready, then SCHED_FIFO with every thread and its physics
        # worker: tests/standin.py), the daemon as `cdcr-ctl --config RIG daemon`.
        from standin import RT_PRIORITY, standin_realtime

        from cdcr_ctl.cli.demo import SIM_NICE, _cli, make_session, running, wait_for_socket

        if self.world != world:
            self.close()
            self._stack = contextlib.ExitStack()
            # The CAN adapter and load cells on loopback TCP, not ptys (syshelp.session: a
            # pty's bytes wait for the kernel's tty worker, which a loaded machine delays).
            self.rig, self.sim = make_session(ROOT / world, self.work, self.runs, tcp_links=True)
            # The daemon as the unit runs it, at SCHED_FIFO (below the stand-in rig): at the
            # simulator config's SCHED_OTHER, a loaded machine starved it and its master
            # heartbeat stopped (the drives' EMCY 0x8130 at load average 22).
            doc = yaml.safe_load(self.rig.read_text())
            doc.setdefault("control", {})["realtime_priority"] = RT_PRIORITY
            self.rig.write_text(yaml.safe_dump(doc, sort_keys=False))
            sim_log = self.tmp / "sim.log"
            cmd = _cli("sim", str(self.sim))
            proc = self._stack.enter_context(running(cmd, sim_log, ready='"ready"', nice=SIM_NICE))
            standin_realtime(proc.pid)
            self.world = world
        if daemon and self._daemon is None:
            assert self.rig is not None
            log = self.tmp / "daemon.log"
            cmd = _cli("--config", str(self.rig), "daemon")
            self._daemon = self._stack.enter_context(running(cmd, log))
            wait_for_socket(self.work / "control.sock", self._daemon, log)
            self._wait_drives_known()

    def _wait_drives_known(self, timeout_s: float = 30.0) -> None:
        """Until the daemon has heard every drive (a reader's `enable` right after the daemon
        started would otherwise race the drives' boot)."""
        from cdcr_ctl.daemon.client import ControlClient

        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with contextlib.suppress(Exception), ControlClient(self.work / "control.sock") as c:
                drives = c.call("status")["drives"]
                if drives and all(d["state"] != "UNKNOWN" for d in drives):
                    return
            time.sleep(0.2)

    def call(self, cmd: str, **args) -> dict | None:
        """One request to the shared daemon (None when it is not running)."""
        from cdcr_ctl.daemon.client import ControlClient

        if self._daemon is None:
            return None
        with ControlClient(self.work / "control.sock") as c:
            return c.call(cmd, **args)

    def settle(self) -> str | None:
        """Before a page: a trip latched since the last page (a drive's heartbeat lost while the
        machine was loaded, between two pages) is acknowledged, as a reader would. Returns what
        was reset, for the test's output."""
        try:
            st = self.call("status")
        except Exception as exc:
            return f"the daemon did not answer status: {exc}"
        if st and st.get("fault"):
            with contextlib.suppress(Exception):
                self.call("reset_fault", confirm=True)
            return f"reset a trip latched between pages: {st['fault']}"
        return None

    def recover_load_trip(self, text: str, stderr: str = "") -> str | None:
        """After a failed ``cdcr-ctl`` command: when the daemon holds a trip the machine's load
        caused (:data:`LOAD_TRIPS`), or the command failed on one (:data:`LOAD_ERRORS`), recover
        as the manual says (``reset-fault``, then ``enable`` unless the command was one of the
        two) and return what was recovered; else None."""
        if not text.startswith("cdcr-ctl "):
            return None
        try:
            st = self.call("status")
        except Exception:
            return None
        fault = (st or {}).get("fault") or {}
        if not LOAD_TRIPS.match(str(fault.get("cause", ""))):
            if not LOAD_ERRORS.search(stderr):
                return None
            fault = {"cause": "during the command", "detail": stderr.strip()[-200:]}
        with contextlib.suppress(Exception):  # the retried command says what still fails
            self.call("reset_fault", confirm=True)
            if not re.search(r"\b(enable|reset-fault)\b", text):
                self.call("enable")
        return f"recovered from a trip of the loaded machine: {fault['cause']} ({fault['detail']})"

    def close(self) -> None:
        self._stack.close()
        self._daemon = None
        self.world = None

    def substitute(self, cmd: str) -> str:
        """The command with the simulated rig's configs swapped for the shared rig's."""
        words = shlex.split(cmd, comments=True)
        if "sim" in words and "cdcr-ctl" in words[0:1]:
            worlds = [w for w in words if w.startswith("config/sim/")]
            self.ensure(worlds[0] if worlds else DEFAULT_WORLD, daemon=False)
            assert self.sim is not None
            for w in worlds:
                cmd = cmd.replace(w, str(self.sim))
        if SIM_RIG in cmd:
            self.ensure(self.world or DEFAULT_WORLD)
            cmd = cmd.replace(SIM_RIG, str(self.rig))
        return cmd

    def is_shared(self, cmd: str) -> bool:
        """A background line the shared rig already serves: the simulator or the daemon."""
        words = shlex.split(cmd, comments=True)
        return words[:1] == ["cdcr-ctl"] and ("sim" in words or "daemon" in words)

    def run(self, cmd: str) -> subprocess.CompletedProcess:
        return run_guarded(cmd, self.cwd, self.env())

    @contextlib.contextmanager
    def background(self, cmd: str, log: Path) -> Iterator[subprocess.Popen]:
        with log.open("w") as out:
            proc = subprocess.Popen(
                ["bash", "-c", f"exec {cmd}"],
                cwd=self.cwd,
                env=self.env(),
                stdout=out,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                start_new_session=True,
            )
        try:
            yield proc
        finally:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()

    def shutdown(self) -> None:
        self.close()
        shutil.rmtree(self.work, ignore_errors=True)


def session_cpu_s(sid: int) -> float:
    """CPU time (s, user + system) of the live processes of session ``sid`` and of the children
    they have reaped, from ``/proc/PID/stat`` (fields 6 session, 14-17 utime, stime, cutime,
    cstime, in clock ticks)."""
    ticks = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            rest = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue  # the process ended while we looked
        if int(rest[3]) == sid:
            ticks += sum(int(v) for v in rest[11:15])
    return ticks / os.sysconf("SC_CLK_TCK")


def run_guarded(
    cmd: str,
    cwd: Path,
    env: dict[str, str],
    limit_s: float = COMMAND_TIMEOUT_S,
    window_s: float = STALL_WINDOW_S,
    stall_cpu_s: float = STALL_CPU_S,
    backstop_s: float = COMMAND_BACKSTOP_S,
    poll_s: float = 1.0,
) -> subprocess.CompletedProcess:
    """``cmd`` in ``bash -o pipefail`` in a session of its own, its output captured. Given up on
    (the session killed, :class:`subprocess.TimeoutExpired` raised with the reason as its
    ``output``) once past ``limit_s`` of wall time it used less than ``stall_cpu_s`` of CPU over
    the last ``window_s``, or past ``backstop_s`` whatever it does."""
    proc = subprocess.Popen(
        ["bash", "-o", "pipefail", "-c", cmd],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
        start_new_session=True,
    )
    t0 = time.monotonic()
    marks: list[tuple[float, float]] = []  # (wall s since start, session CPU s)
    while True:
        try:
            out, err = proc.communicate(timeout=poll_s)
            return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
        except subprocess.TimeoutExpired:
            pass
        now = time.monotonic() - t0
        marks.append((now, session_cpu_s(proc.pid)))
        why = None
        if now > backstop_s:
            why = f"ran over {backstop_s:g} s"
        elif now > limit_s:
            past = [m for m in marks if m[0] <= now - window_s]
            if past and marks[-1][1] - past[-1][1] < stall_cpu_s:
                used = marks[-1][1] - past[-1][1]
                why = (
                    f"ran over {limit_s:g} s and used {used:.2f} s of CPU in the last "
                    f"{window_s:g} s (stalled)"
                )
        if why:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise subprocess.TimeoutExpired(proc.args, now, output=why)


def run_page(rig: DocRig, page: Path) -> list[str]:
    """Run a page's commands; return its failures, each naming the page's line."""
    rel = page.relative_to(ROOT)
    failures: list[str] = []
    note = rig.settle()
    if note:
        print(f"{rel}: {note}")
    with contextlib.ExitStack() as page_procs:
        for block in blocks(page):
            mark = block.mark
            where = f"{rel}:{block.line}"
            if mark.startswith("hardware-only"):
                if not mark.removeprefix("hardware-only").strip(": ").strip():
                    failures.append(f"{where}: hardware-only needs a reason")
                continue
            if mark.startswith("covered-by"):
                for c in block.commands:
                    problem = check_covered_by(mark, c.text)
                    if problem:
                        failures.append(f"{rel}:{c.line}: {problem}")
                continue
            if mark and mark != "background":
                failures.append(f"{where}: unknown mark <!-- cmd: {mark} -->")
                continue
            for c in block.commands:
                try:
                    cmd = rig.substitute(c.text)
                except Exception as exc:  # the shared rig did not start: name the line
                    failures.append(f"{rel}:{c.line}: `{c.text}`: the simulated rig: {exc}")
                    return failures
                if mark == "background":
                    if rig.is_shared(c.text):
                        continue
                    log = rig.tmp / f"bg-{rel.as_posix().replace('/', '_')}-{c.line}.log"
                    proc = page_procs.enter_context(rig.background(cmd, log))
                    time.sleep(1.0)
                    if proc.poll() not in (None, 0):
                        failures.append(
                            f"{rel}:{c.line}: `{c.text}` exited {proc.returncode}:\n"
                            + log.read_text()[-2000:]
                        )
                    continue
                t0 = time.monotonic()
                try:
                    res = rig.run(cmd)
                except subprocess.TimeoutExpired as exc:
                    failures.append(f"{rel}:{c.line}: `{c.text}` {exc.output}")
                    continue
                print(f"{rel}:{c.line}: {time.monotonic() - t0:5.1f} s  {c.text}")
                if res.returncode != 0 and (note := rig.recover_load_trip(c.text, res.stderr)):
                    print(f"{rel}:{c.line}: {note}; running it again")
                    res = rig.run(cmd)
                if res.returncode != 0:
                    failures.append(
                        f"{rel}:{c.line}: `{c.text}` exited {res.returncode}\n"
                        f"--- stdout\n{res.stdout[-2000:]}\n--- stderr\n{res.stderr[-2000:]}"
                        + _rig_state(rig)
                    )
    return failures


def _rig_state(rig: DocRig) -> str:
    """The shared daemon's latched fault and last trips, to tell a documentation error from a
    rig the machine's load tripped."""
    try:
        st = rig.call("status")
    except Exception as exc:
        return f"\n--- daemon status: {exc}"
    if not st:
        return ""
    return f"\n--- daemon: fault {st.get('fault')}, trips {st.get('trips')}"
