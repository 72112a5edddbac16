"""Fuzz benchmark: every parser of outside input with N inputs each (default 10,000).

Targets (``tests/fuzz/targets.py``): the rig-config loader, the trajectory loader (CSV and YAML),
the control-socket protocol, the Modbus RTU and ASCII load-cell parsers, NatNet frames, the tracker
line stream, WitMotion attitude frames, EMCY decoding, the emulated slcan adapter's command parser
and the network joystick's ``struct input_event`` records. Inputs come from hypothesis (random
bytes/structures and mutations of valid seeds). An input fails when the parser raises anything but
its documented error (RigError and subclasses, NatNetDecodeError) or takes more than ``HANG_S`` of
CPU time. Prints, per target: inputs fed, wall time, slowest input (CPU ms), failures (with the
first few inputs that failed).

    nice .venv/bin/python benchmarks/fuzz.py               # 10,000 per target
    nice .venv/bin/python benchmarks/fuzz.py -n 500 --only control_protocol
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

from hypothesis import HealthCheck, given, settings

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "fuzz"))

from targets import HANG_S, TARGETS, Target, check  # noqa: E402


def fuzz(target: Target, n: int) -> dict:
    stats = {"inputs": 0, "failures": 0, "hangs": 0, "slowest_ms": 0.0, "examples": []}

    @settings(
        max_examples=n,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(target.strategy())
    def run(value) -> None:
        stats["inputs"] += 1
        # CPU time of this process: a hang is work, not waiting for a busy machine's scheduler.
        t0 = time.process_time()
        try:
            check(target, value)
            error = None
        except Exception as exc:  # what the benchmark counts
            error = "".join(traceback.format_exception_only(exc)).strip()
        dt = time.process_time() - t0
        stats["slowest_ms"] = max(stats["slowest_ms"], dt * 1e3)
        if dt > HANG_S:
            stats["hangs"] += 1
            error = error or f"took {dt:.2f} s of CPU"
        if error is not None:
            stats["failures"] += 1
            if len(stats["examples"]) < 3:
                stats["examples"].append({"input": repr(value)[:300], "error": error[-300:]})

    t0 = time.perf_counter()
    run()
    stats["seconds"] = round(time.perf_counter() - t0, 2)
    stats["slowest_ms"] = round(stats["slowest_ms"], 2)
    return stats


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=10_000, help="inputs per target")
    ap.add_argument("--only", action="append", default=[], help="target name (repeatable)")
    args = ap.parse_args(argv)
    targets = [t for t in TARGETS if not args.only or t.name in args.only]
    results = {}
    for t in targets:
        res = fuzz(t, args.n)
        results[t.name] = res
        print(
            f"{t.name:22s} inputs {res['inputs']:6d}  {res['seconds']:7.1f} s  "
            f"slowest {res['slowest_ms']:7.1f} ms  "
            f"failures {res['failures']}  hangs {res['hangs']}",
            flush=True,
        )
        for ex in res["examples"]:
            print(f"    {ex['error']}\n      input: {ex['input']}")
    total_fail = sum(r["failures"] for r in results.values())
    short = [k for k, r in results.items() if r["inputs"] < args.n]
    print(json.dumps({"targets": len(results), "failures": total_fail, "short": short}))
    return 1 if total_fail else 0


if __name__ == "__main__":
    sys.exit(main())
