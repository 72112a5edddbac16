"""pyserial URL handlers of the project's own (pyserial's ``protocol_handler_packages``).

``socket://HOST:PORT`` (a serial link carried over TCP, as the simulated rig serves its slcan
adapter and its load-cell transmitters on loopback ports): pyserial's handler sleeps 0.3 s in
every ``close()`` "in case of quick reconnects". A daemon closes two such links when it stops,
so each stop took 0.6 s longer than its work. :mod:`.protocol_socket` is pyserial's handler
with a close that returns when the socket is shut. A listener that serves one client at a time
(:func:`cdcr_ctl.sim.loopback.listen_loopback`) queues a quick reconnect in its backlog until
it has seen the old client go, so nothing relies on the pause. Real serial ports (``/dev/tty*``)
and every other URL keep pyserial's own handlers.

:func:`register` puts this package first in pyserial's search list (once; standard library
and pyserial only, so the drive and sensor layers may both call it before opening a port).
"""

from __future__ import annotations

import serial

#: This package's name, as pyserial's ``serial_for_url`` imports ``<package>.protocol_<scheme>``.
PACKAGE = __name__


def register() -> None:
    """Have ``serial.serial_for_url`` look for a URL's handler here first (idempotent)."""
    if PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.insert(0, PACKAGE)
