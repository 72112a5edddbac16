"""Fixtures and collection rules for every test directory.

``--unit``: ``wallclock`` or ``rest`` runs one part of the suite (``scripts/test`` runs all in
one process).

- ``wallclock``: tests marked ``realtime`` (the simulated rig and the daemon as processes on
  the wall clock: stand-in hardware, heartbeats, stop latency, kills) and the drive-layer files
  whose simulated nodes run in the test's process on the wall clock (:data:`WALLCLOCK_FILES`).
  Beside a second worker under ``stress-ng --cpu 2`` they tripped (five real-time
  tests, "heartbeat lost"; beside the rest at autogroup nice +10, three), serially
  they pass: they need the machine to themselves;
- ``rest``: everything else, whose outcome does not hang on the wall clock.

Within a run with workers (``pytest -n 2 --dist loadgroup``, whatever ``--unit``):

- the tests of :data:`RIG_FILES` (marked ``realtime`` or ``multicore``: a lock-step rig with its
  truth worker, a pool of replay workers; and the drive files above) form one work unit,
  ``rig``: it runs on one worker, one test after the other, so a multi-core test never shares
  the two cores with another rig. The other worker runs the rest beside it, one test at a time.
  In ``--unit rest`` the unit holds the ``multicore`` tests only;
- the longest tests are handed out first (the ``rig`` unit, then ``slow``, then the rest, each
  in file order), so no long test is left to run alone at the end.

The unit is made by :class:`RigGroupScheduling` (xdist's ``pytest_xdist_make_scheduler`` hook),
by file, not by xdist's own ``xdist_group`` mark: pytest-xdist 3.8 marks a group by rewriting
the test's node id, which pytest 9.2 no longer takes, so the groups were silently ignored
(pytest-xdist issue 1386; measured here: two real-time rigs ran side by side). The scheduler
sees node ids only, hence the file list; a marked test outside it fails.

``_close_writer_spares``: a :class:`~cdcr_ctl.runlog.writer.RunLogFactory` starts a spare
run-log writer process ahead of its next run (an interpreter with its imports, ~64 MB). Tests
build factories in this process (directly, through ``LockstepSession`` or an in-process
``Daemon``) and drop them; their spares used to live until pytest exited (14 of them in one
suite run). After each test, the spares of the factories it made are ended.
"""

from __future__ import annotations

import gc
import os
import tempfile

import pytest
from xdist.scheduler import LoadScopeScheduling

from cdcr_ctl.runlog.writer.factory import RunLogFactory

# The ownership locks (cdcr_ctl.ownership) of every daemon, scan and simulator the tests start
# go to a directory of this test process's own, inherited by the processes it starts (as root,
# the default would be /run/cdcr-ctl, shared with a lab's service).
os.environ.setdefault("CDCR_CTL_LOCK_DIR", tempfile.mkdtemp(prefix="cdcr-locks-"))

#: The work unit of the tests marked ``realtime`` or ``multicore``.
RIG_GROUP = "rig"
#: The test files holding them (paths from the project root, as in pytest's node ids), and the
#: drive-layer files whose simulated nodes run in the test's process on the wall clock
#: (heartbeats every 50 ms, feedback watched against ``feedback_timeout_s``): beside a rig test
#: under ``stress-ng --cpu 2`` three of them tripped "heartbeat lost", so they run in
#: the unit too, one after the other, as they did before the suite had two workers.
RIG_FILES = frozenset(
    {
        "tests/discrepancy/test_keypoint_discrepancy.py",
        "tests/docs/test_doc_commands.py",
        "tests/drives/test_csp.py",
        "tests/drives/test_diagnosis.py",
        "tests/drives/test_epos2.py",
        "tests/drives/test_faults.py",
        "tests/drives/test_frames.py",
        "tests/drives/test_lag.py",
        "tests/drives/test_lifecycle.py",
        "tests/drives/test_limits.py",
        "tests/drives/test_nmt_in_flight.py",
        "tests/drives/test_scan.py",
        "tests/drives/test_sdo_frames.py",
        "tests/drives/test_sim_node.py",
        "tests/drives/test_slcan_bus.py",
        "tests/drives/test_stock_canopen.py",
        "tests/drives/test_transports.py",
        "tests/system/test_daemon_stops.py",
        "tests/system/test_demo.py",
        "tests/system/test_demo_ujoint.py",
        "tests/system/test_demo_vertebra.py",
        "tests/system/test_drive_reboot.py",
        "tests/system/test_fault_matrix.py",
        "tests/system/test_joystick_session.py",
        "tests/system/test_lockstep.py",
        "tests/system/test_lockstep_vertebra.py",
        "tests/system/test_lockstep_vs_realtime.py",
        "tests/system/test_recovery.py",
        "tests/system/test_rig_process.py",
        "tests/system/test_runlog_views.py",
        "tests/system/test_service_start.py",
        "tests/system/test_sim_ready.py",
        "tests/system/test_stop_battery.py",
        "tests/system/test_stop_under_load.py",
    }
)


#: The drive-layer files of :data:`RIG_FILES` (no ``realtime`` mark: their simulated nodes run
#: in the test's own process) that the ``wallclock`` unit takes with the marked tests.
WALLCLOCK_FILES = frozenset(f for f in RIG_FILES if f.startswith("tests/drives/"))
#: ``--unit`` choices.
UNITS = ("all", "wallclock", "rest")


def pytest_addoption(parser):
    parser.addoption(
        "--unit",
        choices=UNITS,
        default="all",
        help="run only the wall-clock tests (realtime-marked, WALLCLOCK_FILES), only the rest, "
        "or all (default)",
    )


def _file_of(nodeid: str) -> str:
    return nodeid.split("::", 1)[0]


def _marked(item) -> bool:
    return any(item.get_closest_marker(m) for m in ("realtime", "multicore"))


class RigGroupScheduling(LoadScopeScheduling):
    """xdist's scope scheduling with one scope for every test in :data:`RIG_FILES` and one per
    test elsewhere; the largest scope (the rig unit) goes out first."""

    def _split_scope(self, nodeid: str) -> str:
        return RIG_GROUP if _file_of(nodeid) in RIG_FILES else nodeid


def pytest_xdist_make_scheduler(config, log):
    if config.getvalue("dist") == "loadgroup":
        return RigGroupScheduling(config, log)
    return None


def _on_wall_clock(item) -> bool:
    return bool(item.get_closest_marker("realtime")) or _file_of(item.nodeid) in WALLCLOCK_FILES


def pytest_collection_modifyitems(config, items):
    unit = config.getoption("unit")
    if unit != "all":
        keep = [i for i in items if _on_wall_clock(i) == (unit == "wallclock")]
        dropped = [i for i in items if _on_wall_clock(i) != (unit == "wallclock")]
        if dropped:
            config.hook.pytest_deselected(items=dropped)
        items[:] = keep

    def rank(item) -> int:
        if _file_of(item.nodeid) in RIG_FILES:
            return 0
        return 1 if item.get_closest_marker("slow") else 2

    items.sort(key=rank)  # stable: file order within each rank


def pytest_collection_finish(session):
    """Everything collection made (the test tree, rewritten modules, fixtures: ~200 000 objects
    for the suite) leaves the garbage collector's generations. A full pass over them took 144 ms
    here, in whichever thread allocated at the time, with the interpreter lock held: the
    drive-layer tests run their simulated nodes and master in this process on the wall clock
    (heartbeats every 50 ms, lost after 150 ms), and one lost its drive's heartbeat to a 0.2 s
    stall of the whole process (``tests/drives/test_sim_node.py``, quiet machine). After
    ``gc.freeze()`` a full pass scans only what the tests make. The daemon's loop does the same
    when it starts (``cdcr_ctl/control/loop/cycle.py``)."""
    gc.collect()
    gc.freeze()


@pytest.fixture(autouse=True)
def _in_the_rig_unit(request):
    """A marked test outside :data:`RIG_FILES` would run beside a real-time rig: it fails."""
    if _marked(request.node) and _file_of(request.node.nodeid) not in RIG_FILES:
        pytest.fail(f"{_file_of(request.node.nodeid)} is not in tests/conftest.py RIG_FILES")


@pytest.fixture(autouse=True)
def _close_writer_spares(monkeypatch):
    made: list[RunLogFactory] = []
    init = RunLogFactory.__init__

    def recording_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(self)

    monkeypatch.setattr(RunLogFactory, "__init__", recording_init)
    yield
    for factory in list(made):
        factory.close_spare()
