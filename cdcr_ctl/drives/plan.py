"""Check every SDO write the configuration plans, before the first CAN frame, against what the
drive accepts: the object exists, it is writable, the data has its type's length, the value is in
its range. Pure but for reading a device description file.

Where the limits come from, per drive: the device description the config names (``eds:``, an
EDS/DCF/XDD read with canopen's own :func:`~canopen.objectdictionary.import_od`; a relative path
is relative to the config file), else the project's table for the drive's family
(:mod:`cdcr_ctl.drives.limits`). A refused write is a :class:`~cdcr_ctl.errors.ConfigError`
naming the config file, the key path whose value made the write, and the object.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from canopen.objectdictionary import import_od

from cdcr_ctl.config.drives import CanBusConfig, DriveConfig
from cdcr_ctl.drives import epos
from cdcr_ctl.drives.limits import ObjectTable, check_write, shipped_table, table_from_od
from cdcr_ctl.errors import ConfigError


def drive_key(d: DriveConfig) -> str:
    """Key path of a drive in the config (by name: the group's order need not be the file's)."""
    return f"drives[name={d.name}]"


def eds_path(d: DriveConfig, file: str = "") -> Path | None:
    """The device description file of drive ``d`` (relative to the config file), or None."""
    if not d.eds:
        return None
    p = Path(d.eds).expanduser()
    if not p.is_absolute() and file:
        p = Path(file).parent / p
    return p


def object_table(d: DriveConfig, file: str = "") -> ObjectTable:
    """The limits drive ``d`` is checked against: its ``eds:`` file, else the shipped table."""
    path = eds_path(d, file)
    if path is None:
        return shipped_table(d.type)
    try:
        od = import_od(str(path), d.node_id)
    except FileNotFoundError as exc:
        raise ConfigError(file, f"{drive_key(d)}.eds", "no such file", str(path)) from exc
    except Exception as exc:  # canopen raises what its parsers raise: name the file
        raise ConfigError(
            file, f"{drive_key(d)}.eds", f"not a readable EDS/DCF/XDD ({exc})", str(path)
        ) from exc
    return table_from_od(od, f"device description {path.name}")


def check_writes(
    d: DriveConfig, writes: Sequence[epos.SdoWrite], table: ObjectTable, file: str = ""
) -> None:
    """Raise ConfigError for the first write ``table`` refuses (file, key path, object)."""
    for w in writes:
        refusal = check_write(table, w.index, w.sub, w.data)
        if refusal is not None:
            key = w.key or drive_key(d)
            raise ConfigError(
                file,
                key,
                f"node {d.node_id} would refuse the write of {w.what or 'an object'} "
                f"(SDO abort 0x{refusal.code:08X}): {refusal.text}",
            )


def planned_writes(
    d: DriveConfig, bus: CanBusConfig, table: ObjectTable, file: str = ""
) -> list[epos.SdoWrite]:
    """Every SDO write configuring and homing drive ``d`` plans (configuration, then homing)."""
    return epos.configuration_writes(d, bus, file, table) + epos.homing_writes(d)


def check_plans(drives: Sequence[DriveConfig], bus: CanBusConfig, file: str = "") -> None:
    """Check the planned writes of every drive; the first refusal raises ConfigError."""
    for d in drives:
        table = object_table(d, file)
        check_writes(d, planned_writes(d, bus, table, file), table, file)
