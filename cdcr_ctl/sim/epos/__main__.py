"""``python -m cdcr_ctl.sim.epos [RIG.yaml] [--node ID:KIND ...] [--link PATH | --tcp]``:
simulated EPOS drives behind an slcan pseudo-terminal (or, ``--tcp``, an slcan adapter on a
loopback TCP port), in their own process.

Prints the pty path (or the ``--link`` symlink, or ``socket://127.0.0.1:PORT``) on the first
line, then serves until SIGTERM or SIGINT. A controller connects with python-can
``interface="slcan", channel=<that line>``.

Fault injection on stdin, one command per line, each answered by one line (``ok ...`` / ``error
...``): ``fault NODE CODE`` (EMCY code, e.g. ``fault 2 0x8611``), ``silent NODE``, ``recover
NODE``, ``heartbeat-stop NODE``, ``heartbeat-start NODE``, ``unplug`` (the adapter vanishes),
``positions`` (actual positions, counts, drive order), ``states``, ``stats`` (JSON: SYNCs seen,
missed set-points, SYNC intervals per drive), ``reset-stats``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

from cdcr_ctl.config import load_rig_config
from cdcr_ctl.sim.epos.rig import SimDriveBus


def _node_spec(text: str) -> tuple[int, str]:
    nid, _, kind = text.partition(":")
    kind = kind or "epos4"
    if kind not in ("epos4", "epos2"):
        raise argparse.ArgumentTypeError(f"{text!r}: kind must be epos4 or epos2")
    try:
        return int(nid), kind
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected NODE_ID[:KIND]") from None


def command(drives: SimDriveBus, line: str) -> str:
    """Execute one stdin command; the answer line."""
    words = line.split()
    if not words:
        return "error empty command"
    verb, args = words[0], words[1:]
    try:
        if verb == "positions":
            return "ok " + " ".join(str(p) for p in drives.actual_positions())
        if verb == "states":
            return "ok " + " ".join(n.state.name for n in drives.nodes)
        if verb == "stats":
            return "ok " + json.dumps(drives.stats())
        if verb == "reset-stats":
            drives.reset_stats()
            return "ok reset-stats"
        if verb == "unplug":
            drives.unplug()
            return "ok unplugged"
        node = drives.node(int(args[0]))
        if verb == "fault":
            node.inject_fault(int(args[1], 0))
        elif verb == "silent":
            node.go_silent()
        elif verb == "recover":
            node.recover()
        elif verb == "heartbeat-stop":
            node.stop_heartbeat()
        elif verb == "heartbeat-start":
            node.start_heartbeat()
        else:
            return f"error unknown command {verb!r}"
        return f"ok {verb} {node.node_id}"
    except (IndexError, ValueError, KeyError) as exc:
        return f"error {verb}: {exc}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m cdcr_ctl.sim.epos",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("rig", nargs="?", help="rig config (YAML): its drives and bit rate")
    ap.add_argument(
        "--node",
        action="append",
        type=_node_spec,
        default=[],
        help="a drive as NODE_ID[:epos4|epos2] (instead of a rig config)",
    )
    ap.add_argument("--link", default=None, help="symlink to create to the pty")
    ap.add_argument(
        "--tcp",
        action="store_true",
        help="serve slcan on a loopback TCP port instead of a pty (prints socket://...)",
    )
    ap.add_argument("--bitrate", type=int, default=None, help="bus bit rate (default: rig's)")
    ap.add_argument(
        "--free-run",
        action="store_true",
        help="advance the drives on the wall clock while no SYNC comes",
    )
    ap.add_argument(
        "--lag-cycles",
        type=int,
        default=1,
        help="feedback lag of every drive in SYNCs (1: as a real EPOS; 0: none)",
    )
    args = ap.parse_args(argv)
    if args.rig is None and not args.node:
        ap.error("give a rig config or at least one --node")
    specs = load_rig_config(args.rig) if args.rig else args.node
    if args.tcp and args.link:
        ap.error("--link names a pty; a --tcp adapter has an address")
    drives = SimDriveBus(
        specs,
        "slcan",
        link=args.link,
        bitrate=args.bitrate,
        free_run=args.free_run,
        tcp=args.tcp,
        lag_cycles=args.lag_cycles,
    ).start()
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())

    def serve_stdin() -> None:
        for line in sys.stdin:
            print(command(drives, line), flush=True)

    threading.Thread(target=serve_stdin, name="sim-epos-stdin", daemon=True).start()
    print(drives.channel_path, flush=True)
    stop.wait()
    drives.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
