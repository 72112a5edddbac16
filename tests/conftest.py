"""Fixtures for every test directory.

``_close_writer_spares``: a :class:`~cdcr_ctl.runlog.writer.RunLogFactory` starts a spare
run-log writer process ahead of its next run (an interpreter with its imports, ~64 MB). Tests
build factories in this process (directly, through ``LockstepSession`` or an in-process
``Daemon``) and drop them; their spares used to live until pytest exited (14 of them in one
suite run). After each test, the spares of the factories it made are ended.
"""

from __future__ import annotations

import pytest

from cdcr_ctl.runlog.writer import RunLogFactory


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
