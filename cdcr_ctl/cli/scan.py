"""``cdcr-ctl scan``: the nodes on the rig's CAN bus, with device type 0x1000 and identity 0x1018,
compared with the config (missing node, wrong product, wrong node id). The day-one bring-up tool:
it opens the bus the config names itself, so it refuses while a daemon owns that bus (one master
on a bus, :mod:`cdcr_ctl.ownership`): stop the daemon first."""

from __future__ import annotations

import click

from cdcr_ctl.cli.app import Ctx
from cdcr_ctl.errors import CommError, ConfigError
from cdcr_ctl.ownership import Ownership, bus_key


@click.command("scan")
@click.option(
    "--timeout",
    "timeout_s",
    type=float,
    default=0.3,
    show_default=True,
    help="How long answers to the device-type requests are collected (s).",
)
@click.pass_obj
def scan(obj: Ctx, timeout_s: float) -> None:
    """List the nodes on the bus of --config and compare them with its drives (read only: no NMT
    command, no SDO write). Exit status 1 when the bus and the config differ."""
    import can

    from cdcr_ctl.config import load_rig_config
    from cdcr_ctl.drives.canbus import open_bus
    from cdcr_ctl.drives.scan import compare, scan_bus

    if not obj.config:
        raise ConfigError("", "--config", "scan needs the rig config whose bus to scan")
    cfg = load_rig_config(obj.config)
    # The bus's lock, as a daemon takes it: while a daemon owns the bus this refuses before
    # opening it (naming the daemon's pid), and a daemon started during the scan refuses.
    with Ownership() as owner:
        owner.take(bus_key(cfg.can.interface, cfg.can.channel))
        bus = open_bus(cfg.can)
        try:
            nodes = scan_bus(bus, timeout_s=timeout_s)
        except (can.CanError, OSError) as exc:  # the adapter failed mid-scan: say so, no trace
            raise CommError(
                f"CAN {cfg.can.interface}:{cfg.can.channel}: scan failed ({exc})"
            ) from exc
        finally:
            bus.shutdown()
    issues = compare(nodes, cfg.drives)
    result = {
        "bus": f"{cfg.can.interface}:{cfg.can.channel} @ {cfg.can.bitrate} bit/s",
        "nodes": [n.as_dict() for n in nodes],
        "issues": issues,
        "matches_config": not issues,
    }
    lines = [f"bus {result['bus']}: {len(nodes)} node(s)"]
    for n in nodes:
        d = n.as_dict()
        lines.append(
            f"  node {n.node_id:3d}  {n.name or '?':12s} device type {d['device_type']}  "
            f"vendor {d['vendor_id']}  product {d['product_code']}  revision {d['revision']}  "
            f"serial {d['serial']}"
        )
    lines += [f"  ! {i}" for i in issues] or ["  matches the config"]
    obj.emit(result, "\n".join(lines))
    if issues:
        raise click.exceptions.Exit(1)
