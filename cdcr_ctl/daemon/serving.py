"""What the one-process daemon (:class:`~cdcr_ctl.daemon.service.Daemon`) and the front
process (:class:`~cdcr_ctl.daemon.front.FrontDaemon`) do alike to serve: open the control
socket behind the intake, and hold the stop signals while they run."""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Callable, Iterator
from typing import Any

from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.daemon.intake import Intake
from cdcr_ctl.daemon.server import ControlServer


def open_control_server(
    cfg: RigConfig, handle: Callable[..., Any], intake: Intake
) -> ControlServer:
    """Start ``intake`` and the control socket of ``cfg.daemon`` serving ``handle``, its
    trajectory spools parsed by ``intake``."""
    intake.start()
    return ControlServer(
        cfg.daemon.socket_path,
        handle,
        mode=cfg.daemon.socket_mode,
        spooler=intake.parse_spooled,
        spool_dir=intake.dir,
    ).start()


@contextlib.contextmanager
def stop_signals(install: bool, handler: Callable[[int, Any], None]) -> Iterator[None]:
    """With ``install``: SIGTERM and SIGINT go to ``handler`` and SIGXFSZ is ignored while the
    block runs; the process's handlers as they were afterwards (a daemon embedded in a larger
    program). A file-size limit (RLIMIT_FSIZE) must fail the write (EFBIG, handled like a full
    disk by the run log, or a spool write refused) rather than kill the controller with the
    drives enabled."""
    previous: dict[int, Any] = {}
    if install:
        for sig in (signal.SIGTERM, signal.SIGINT):
            previous[sig] = signal.signal(sig, handler)
        previous[signal.SIGXFSZ] = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    try:
        yield
    finally:
        for sig, handler_was in previous.items():
            signal.signal(sig, handler_was)
