"""The package's rooms and the way its imports point (docs/architecture.md "Layers").

Walks every module of ``cdcr_ctl`` with :mod:`ast` (every import counts: one inside a function,
as a lazy import that dodges a cycle is still a cycle, and one under ``if TYPE_CHECKING:``, as a
type-only import that closes a circle still ties the rooms together) and fails on

- an import cycle between modules (the command modules that ``cdcr_ctl.cli.main``'s lazy command
  group imports by name count as that module's imports);
- an import against the layer order
  model <- config <- drives, sensors, runlog <- control, sim, identify, discrepancy <- daemon <- cli
  (a layer may import its own layer and the layers below it);
- production code importing the simulator (``cdcr_ctl.sim``): only the CLI commands that start a
  simulated rig may, and they are named here.
"""

from __future__ import annotations

import ast
from functools import cache
from pathlib import Path

PKG = Path(__file__).resolve().parents[2] / "cdcr_ctl"

#: Layer of each top-level subpackage (higher may import lower or equal, never higher).
LAYERS: dict[str, int] = {
    "__init__": 0,  # the package root: imports only blas (the BLAS thread policy)
    "blas": 0,
    "errors": 0,
    "firstuse": 0,  # package attributes imported on first use (standard library only)
    "ownership": 0,  # one owner per bus, socket and simulator link (flock; standard library)
    "seriallink": 0,  # pyserial URL handlers (pyserial and the standard library only)
    "model": 0,
    "config": 1,
    "drives": 2,
    "sensors": 2,
    "runlog": 2,
    "control": 3,
    "sim": 3,
    "identify": 3,
    "discrepancy": 3,
    "analysis": 3,
    "daemon": 4,
    "cli": 5,
    "__main__": 5,
}
#: Siblings in the same layer that must not import each other (the simulator stays apart).
APART = {("control", "sim"), ("identify", "sim"), ("discrepancy", "sim"), ("analysis", "sim")}
#: CLI modules that start the simulated rig (`cdcr-ctl sim`, `sim --lockstep`): the only
#: modules outside `cdcr_ctl.sim` allowed to import it.
SIM_ENTRY_POINTS = {"cdcr_ctl.cli.commands", "cdcr_ctl.cli.lockstep"}


def modules() -> dict[str, Path]:
    out = {}
    for p in PKG.rglob("*.py"):
        parts = p.relative_to(PKG.parent).with_suffix("").parts
        name = ".".join(parts)
        out[name.removesuffix(".__init__")] = p
    return out


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The package modules ``name`` imports (``from a import b`` is module ``a.b`` if it is one)."""
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            for alias in node.names:
                for cand in (f"{base}.{alias.name}", base):
                    if cand in known:
                        found.add(cand)
                        break
        elif isinstance(node, ast.Import):
            for alias in node.names:
                mod = alias.name
                while mod and mod not in known:
                    mod = mod.rpartition(".")[0]
                if mod:
                    found.add(mod)
    found.discard(name)
    return found


def imported_by_name() -> dict[str, set[str]]:
    """Imports made from a string at run time: the command modules of the CLI's lazy group
    (:data:`cdcr_ctl.cli.main.COMMANDS`, ``"module.attribute"``), counted as imports of
    ``cdcr_ctl.cli.main``; the modules of the packages' ``LAZY`` tables, as imports of the
    package; the design registry's truths and demos (``"module:attribute"``), as imports of the
    modules that resolve them."""
    from cdcr_ctl import identify, model, runlog
    from cdcr_ctl.cli.main import COMMANDS
    from cdcr_ctl.config.registry import DESIGNS

    def named(attr: str) -> set[str]:
        refs = (getattr(d, attr) for d in DESIGNS.values())
        return {r.partition(":")[0] for r in refs if isinstance(r, str)}

    return {
        "cdcr_ctl.cli.main": {path.rpartition(".")[0] for path in COMMANDS.values()},
        # the packages' attributes imported on first use (cdcr_ctl.firstuse)
        "cdcr_ctl.identify": set(identify.LAZY.values()),
        "cdcr_ctl.model": set(model.LAZY.values()),
        "cdcr_ctl.runlog": set(runlog.LAZY.values()),
        # the design registry's plug-ins, resolved by the layer that uses them
        "cdcr_ctl.sim.design_truth": named("truth"),
        "cdcr_ctl.cli.demo": named("demo"),
    }


@cache  # one walk of the package for the module's tests (they only read it)
def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    g = {n: imports_of(n, p, known) for n, p in mods.items()}
    for name, targets in imported_by_name().items():
        assert targets <= known, f"{name} names modules that do not exist: {targets - known}"
        g[name] |= targets
    return g


def top(name: str) -> str:
    parts = name.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def find_cycles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def test_the_walker_finds_a_cycle_and_a_layer_break():
    g = {"cdcr_ctl.model.a": {"cdcr_ctl.config.b"}, "cdcr_ctl.config.b": {"cdcr_ctl.model.a"}}
    assert find_cycles(g) == [["cdcr_ctl.config.b", "cdcr_ctl.model.a"]]
    assert layer_breaks(g) == [("cdcr_ctl.model.a", "cdcr_ctl.config.b")]


def test_the_walker_counts_type_only_and_lazy_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n"
        "    from cdcr_ctl.daemon.service import Daemon\n"
        "def f():\n"
        "    from cdcr_ctl.daemon import status\n",
        encoding="utf-8",
    )
    known = {"cdcr_ctl.daemon.service", "cdcr_ctl.daemon.status", "cdcr_ctl.daemon.m"}
    found = imports_of("cdcr_ctl.daemon.m", src, known)
    assert found == {"cdcr_ctl.daemon.service", "cdcr_ctl.daemon.status"}


def layer_breaks(g: dict[str, set[str]]) -> list[tuple[str, str]]:
    bad = []
    for a, deps in g.items():
        la = top(a)
        for b in deps:
            lb = top(b)
            if la == lb or lb in ("__init__",):
                continue
            if la not in LAYERS or lb not in LAYERS:
                bad.append((a, b))  # a new subpackage must be given its layer above
            elif LAYERS[lb] > LAYERS[la] or (la, lb) in APART:
                bad.append((a, b))
    return sorted(bad)


def test_no_import_cycles():
    assert find_cycles(graph()) == []


def test_imports_follow_the_layer_order():
    assert layer_breaks(graph()) == []


def test_production_code_never_imports_the_simulator():
    g = graph()
    offenders = sorted(
        (a, b)
        for a, deps in g.items()
        for b in deps
        if top(b) == "sim" and top(a) != "sim" and a not in SIM_ENTRY_POINTS
    )
    assert offenders == []
