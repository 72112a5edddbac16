"""A local joystick through python-evdev (optional dependency, imported only when one is opened)."""

from __future__ import annotations

import select
import time
from collections.abc import Iterator
from typing import Any

from cdcr_ctl.config.tracking import JoystickConfig
from cdcr_ctl.errors import SensorError
from cdcr_ctl.sensors.joystick.codes import EV_ABS, Event, axis_code
from cdcr_ctl.sensors.joystick.reader import AxisRange, Joystick, _config_ranges
from cdcr_ctl.sensors.sample import Clock

#: Longest wait of the evdev source for an event before yielding an idle tick (s).
EVDEV_POLL_S = 0.02


# -- evdev ----------------------------------------------------------------------------------


def _import_evdev(device: str) -> Any:
    try:
        import evdev  # optional dependency: imported only when a real joystick is opened
    except ImportError as exc:
        raise SensorError(
            device,
            "python-evdev is not installed: pip install 'cdcr-ctl[joystick]' (or evdev)",
        ) from exc
    return evdev


def _abs_info(device: Any) -> dict[int, Any]:
    caps = device.capabilities(absinfo=True)
    return {code: info for code, info in caps.get(EV_ABS, [])}


def _find_device(evdev: Any, codes: tuple[int, int]) -> Any:
    for path in evdev.list_devices():
        try:
            dev = evdev.InputDevice(path)
        except OSError:
            continue
        if all(c in _abs_info(dev) for c in codes):
            return dev
        dev.close()
    return None


def _evdev_events(device: Any, name: str) -> Iterator[Event | None]:
    fd = device.fd
    while True:
        try:
            ready, _, _ = select.select([fd], [], [], EVDEV_POLL_S)
            if not ready:
                yield None
                continue
            for ev in device.read():
                yield (ev.type, ev.code, ev.value)
        except BlockingIOError:
            yield None
        except OSError as exc:
            raise SensorError(name, f"joystick disconnected: {exc}") from exc


def open_evdev_joystick(
    cfg: JoystickConfig, *, clock: Clock = time.monotonic, start: bool = True
) -> Joystick:
    """Open the evdev device of ``cfg`` (or the first with both axes) and start a reader.

    Axis ranges come from the device's absinfo; ``cfg.axis_range``, when given, overrides
    them for the two steering axes. Raises :class:`SensorError` when python-evdev is missing,
    the device cannot be opened or lacks an axis; ValueError for an unknown axis name.
    """
    codes = (axis_code(cfg.axis_x), axis_code(cfg.axis_y))
    where = cfg.device or "evdev"
    evdev = _import_evdev(where)
    try:
        device = evdev.InputDevice(cfg.device) if cfg.device else _find_device(evdev, codes)
    except OSError as exc:
        raise SensorError(where, f"cannot open joystick: {exc}") from exc
    if device is None:
        raise SensorError(where, f"no input device has both {cfg.axis_x} and {cfg.axis_y}")
    name = str(getattr(device, "path", where))
    info = _abs_info(device)
    missing = [n for n, c in zip((cfg.axis_x, cfg.axis_y), codes, strict=True) if c not in info]
    if missing:
        device.close()
        raise SensorError(name, f"joystick has no axis {', '.join(missing)}")
    ranges = {c: AxisRange(i.min, i.max) for c, i in info.items() if i.max > i.min}
    ranges.update(_config_ranges(cfg))

    def resync() -> tuple[dict[int, int], list[int]]:
        now = _abs_info(device)
        return {c: i.value for c, i in now.items()}, list(device.active_keys())

    stick = Joystick(
        _evdev_events(device, name),
        name=name,
        axis_x=cfg.axis_x,
        axis_y=cfg.axis_y,
        axis_ranges=ranges,
        deadband=cfg.deadband,
        invert_x=cfg.invert_x,
        invert_y=cfg.invert_y,
        initial={c: i.value for c, i in info.items()},
        resync=resync,
        closer=device.close,
        clock=clock,
    )
    return stick.start() if start else stick
