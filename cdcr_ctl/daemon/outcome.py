"""Results and errors across a process boundary as plain tuples (the project's errors do not
survive pickling): :func:`encode_outcome` on the side that runs the call, :func:`outcome` on
the side that waits for it. Used by the rig process's command server and by the intake's
worker processes."""

from __future__ import annotations

import builtins
from collections.abc import Callable
from typing import Any

from cdcr_ctl.daemon.protocol import ProtocolError
from cdcr_ctl.errors import ConfigError, RigError


def encode_outcome(
    fn: Any, *args: Any, on_bug: Callable[[Exception], tuple[Any, ...]]
) -> tuple[Any, ...]:
    """Run ``fn(*args)``; ``("ok", result)`` or the error as a plain tuple :func:`outcome`
    raises again on the other side. Any other exception (a bug) becomes ``on_bug(exc)``."""
    try:
        return ("ok", fn(*args))
    except ConfigError as exc:
        return ("config", exc.file, exc.key, exc.detail)
    except ProtocolError as exc:
        return ("protocol", str(exc), exc.field)
    except RigError as exc:
        return ("rig", str(exc))
    except Exception as exc:
        return on_bug(exc)


def outcome(out: tuple[Any, ...]) -> Any:
    """The result of an :func:`encode_outcome` tuple, or its error raised."""
    kind = out[0]
    if kind == "ok":
        return out[1]
    if kind == "config":
        raise ConfigError(out[1], out[2], out[3])
    if kind == "protocol":
        exc = ProtocolError("", out[2])
        exc.args = (out[1],)
        raise exc
    if kind == "internal":
        cls = getattr(builtins, out[1], None)
        if not (isinstance(cls, type) and issubclass(cls, Exception)):
            cls = RuntimeError
        raise cls(out[2])
    raise RigError(out[1])
