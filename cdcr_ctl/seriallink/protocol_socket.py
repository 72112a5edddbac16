"""``socket://HOST:PORT``: pyserial's TCP handler without its 0.3 s sleep on close
(:mod:`cdcr_ctl.seriallink`). Opening, reading, writing and the URL's options are pyserial's."""

from __future__ import annotations

import contextlib
import socket

from serial.urlhandler import protocol_socket


class Serial(protocol_socket.Serial):
    """pyserial's ``socket://`` port whose ``close()`` shuts and closes the socket and returns."""

    def close(self) -> None:
        if not self.is_open:
            return
        sock, self._socket = self._socket, None
        if sock is not None:
            # As pyserial's: the peer sees the end at once; errors of a link already gone are
            # not the closer's concern.
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(OSError):
                sock.close()
        self.is_open = False
