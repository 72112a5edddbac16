"""Fixtures and collection rules for every test directory.

Parallel workers (``scripts/test`` runs pytest-xdist ``-n 2 --dist loadgroup``):

- a test marked ``realtime`` runs the simulated rig and the daemon as processes on the wall clock
  (stand-in hardware, heartbeats, stop latency, kills); a test marked ``multicore`` keeps two
  cores busy or more (a lock-step rig: its loop process and its truth worker; a pool of replay
  workers). Both join the xdist group ``rig``: the group runs on one worker, one test after the
  other, so a real-time rig never shares the two cores with another rig or with a multi-core
  test. The other worker runs the rest of the suite beside it, one test at a time, about one core:
  a lighter neighbour than the ``stress-ng --cpu 2`` these tests must pass under;
- the longest tests are handed out first (the ``rig`` group, then ``slow``, then the rest, each
  in file order), so no long test is left to run alone at the end.

``_close_writer_spares``: a :class:`~cdcr_ctl.runlog.writer.RunLogFactory` starts a spare
run-log writer process ahead of its next run (an interpreter with its imports, ~64 MB). Tests
build factories in this process (directly, through ``LockstepSession`` or an in-process
``Daemon``) and drop them; their spares used to live until pytest exited (14 of them in one
suite run). After each test, the spares of the factories it made are ended.
"""

from __future__ import annotations

import pytest

from cdcr_ctl.runlog.writer import RunLogFactory

#: The xdist group of the tests marked ``realtime`` or ``multicore``.
RIG_GROUP = "rig"


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook reads the group marks
def pytest_collection_modifyitems(config, items):
    def in_rig_group(item) -> bool:
        return any(item.get_closest_marker(m) for m in ("realtime", "multicore"))

    def rank(item) -> int:
        if in_rig_group(item):
            return 0
        return 1 if item.get_closest_marker("slow") else 2

    for item in items:
        if in_rig_group(item):
            item.add_marker(pytest.mark.xdist_group(RIG_GROUP))
    items.sort(key=rank)  # stable: file order within each rank


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
