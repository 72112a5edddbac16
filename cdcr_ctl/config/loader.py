"""Load and validate YAML config files; every error names the file, the key path and the value.

A config may name a parent with ``extends: other.yaml`` (its keys are merged on top of the
parent's: the simulated rig's config is the real rig's with other ports), and may list ``overlays``:
further YAML files merged on top in order, e.g. the fitted parameters written by
``cdcr-ctl identify``. Paths are relative to the file that names them. Mappings merge key by
key; lists of mappings that carry a ``name`` merge item by item on that name; anything else is
replaced.
An error in a key that came from an overlay names the overlay file.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from cdcr_ctl.config.designs import check_design
from cdcr_ctl.config.keys import KeyPath, format_key
from cdcr_ctl.config.schema import RigConfig
from cdcr_ctl.errors import ConfigError, ConfigErrors

M = TypeVar("M", bound=BaseModel)


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader reading ``1.0e6``, ``1e6`` and ``-2E-3`` as numbers.

    YAML 1.1 (PyYAML) wants a dot and a signed exponent (``1.0e+6``) and reads ``1.0e6`` as a
    string; YAML 1.2 and every engineer read it as a number.
    """


_Loader.yaml_implicit_resolvers = {
    k: list(v) for k, v in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def read_yaml(path: str | Path) -> Any:
    """Parse one YAML file; a missing file or a syntax error becomes a :class:`ConfigError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(str(p), "", f"cannot read config file: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(str(p), f"byte {exc.start}", "not UTF-8 text") from exc
    try:
        return yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1} column {mark.column + 1}" if mark else "YAML"
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(str(p), where, f"YAML syntax error: {problem}") from exc


def merge_tree(base: Any, over: Any, path: KeyPath, origin: dict[KeyPath, str], src: str) -> Any:
    """Merge ``over`` onto ``base``; record in ``origin`` which paths ``src`` supplied."""
    if isinstance(base, dict) and isinstance(over, dict):
        out = dict(base)
        for key, value in over.items():
            out[key] = (
                merge_tree(base[key], value, (*path, key), origin, src)
                if key in base
                else _mark(value, (*path, key), origin, src)
            )
        return out
    if _named_list(base) and _named_list(over):
        out_list = list(base)
        index = {item["name"]: i for i, item in enumerate(out_list)}
        for item in over:
            if item["name"] in index:
                i = index[item["name"]]
                out_list[i] = merge_tree(out_list[i], item, (*path, i), origin, src)
            else:
                out_list.append(_mark(item, (*path, len(out_list)), origin, src))
        return out_list
    return _mark(over, path, origin, src)


def _mark(value: Any, path: KeyPath, origin: dict[KeyPath, str], src: str) -> Any:
    origin[path] = src
    return value


def _named_list(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(v, dict) and "name" in v for v in value)


def _origin_of(path: KeyPath, origin: Mapping[KeyPath, str], default: str) -> str:
    for n in range(len(path), 0, -1):
        if path[:n] in origin:
            return origin[path[:n]]
    return default


def validate_mapping(
    data: Any,
    model: type[M],
    file: str,
    origin: Mapping[KeyPath, str] | None = None,
) -> M:
    """Validate parsed YAML against a pydantic model; raise :class:`ConfigErrors` naming keys."""
    if not isinstance(data, dict):
        raise ConfigError(file, "", f"top level must be a mapping, not {type(data).__name__}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = []
        for err in exc.errors(include_url=False):
            loc: KeyPath = tuple(err["loc"])
            value = err.get("input")
            if err["type"] == "missing":
                value = None
            elif isinstance(value, dict):
                value = None  # a whole mapping is noise; the key path says where
            src = _origin_of(loc, origin or {}, file)
            msg = err["msg"].removeprefix("Value error, ")
            errors.append(ConfigError(src, format_key(loc), msg, value))
        raise ConfigErrors(errors) from exc


def load_yaml_model(path: str | Path, model: type[M]) -> M:
    """Read one YAML file (with its ``overlays``) and validate it against ``model``."""
    data, origin = _read_with_overlays(Path(path))
    return validate_mapping(data, model, str(path), origin)


#: How deep ``extends`` chains may go (a cycle is an error, not a hang).
MAX_EXTENDS_DEPTH = 8


def _read_with_overlays(path: Path, depth: int = 0) -> tuple[Any, dict[KeyPath, str]]:
    data = read_yaml(path)
    origin: dict[KeyPath, str] = {}
    if isinstance(data, dict) and "extends" in data:
        parent_rel = data.pop("extends")
        if not isinstance(parent_rel, str):
            raise ConfigError(str(path), "extends", "must be a file path", parent_rel)
        if depth >= MAX_EXTENDS_DEPTH:
            raise ConfigError(str(path), "extends", f"chain deeper than {MAX_EXTENDS_DEPTH}")
        parent_path = (path.parent / parent_rel).resolve()
        parent, parent_origin = _read_with_overlays(parent_path, depth + 1)
        if not isinstance(parent, dict):
            raise ConfigError(str(parent_path), "", "top level must be a mapping")
        # Keys the parent supplied are the parent's (or its own parents'/overlays') to answer for.
        origin = {(k,): str(parent_path) for k in parent}
        origin.update(parent_origin)
        data = merge_tree(parent, data, (), origin, str(path))
    if not isinstance(data, dict) or "overlays" not in data:
        return data, origin
    overlays = data.pop("overlays")
    if not isinstance(overlays, list) or not all(isinstance(o, str) for o in overlays):
        raise ConfigError(str(path), "overlays", "must be a list of file paths", overlays)
    for rel in overlays:
        over_path = (path.parent / rel).resolve()
        over = read_yaml(over_path)
        if not isinstance(over, dict):
            raise ConfigError(str(over_path), "", "an overlay must be a mapping")
        data = merge_tree(data, over, (), origin, str(over_path))
    return data, origin


def load_rig_config(path: str | Path) -> RigConfig:
    """Load, merge overlays, validate and cross-check a rig config.

    Raises :class:`ConfigError` (or :class:`ConfigErrors` listing every problem found) before
    anything else runs: no bus is opened and no motor is enabled on a bad config.
    """
    path = Path(path)
    data, origin = _read_with_overlays(path)
    cfg = validate_mapping(data, RigConfig, str(path), origin)
    problems = cross_check(cfg)
    if problems:
        raise ConfigErrors(
            [
                ConfigError(_origin_of(k, origin, str(path)), format_key(k), m, v)
                for k, m, v in problems
            ]
        )
    return cfg


def cross_check(cfg: RigConfig) -> list[tuple[KeyPath, str, Any]]:
    """References between sections: names exist, are unique, node ids and slaves are unique."""
    problems: list[tuple[KeyPath, str, Any]] = []
    robot = cfg.robot

    def unique(items: list[Any], attr: str, where: KeyPath) -> set[Any]:
        seen: set[Any] = set()
        for i, item in enumerate(items):
            value = getattr(item, attr)
            if value in seen:
                problems.append(((*where, i, attr), f"duplicate {attr}", value))
            seen.add(value)
        return seen

    segments = unique(robot.segments, "name", ("robot", "segments"))
    cables = unique(robot.cables, "name", ("robot", "cables"))
    pulleys = unique(robot.pulleys, "name", ("robot", "pulleys"))
    for i, cable in enumerate(robot.cables):
        if cable.segment not in segments:
            problems.append(
                (
                    ("robot", "cables", i, "segment"),
                    f"no segment of that name {sorted(segments)}",
                    cable.segment,
                )
            )
        for j, pulley in enumerate(cable.pulleys):
            if pulley not in pulleys:
                problems.append(
                    (("robot", "cables", i, "pulleys", j), "no pulley of that name", pulley)
                )
    for s, seg in enumerate(robot.segments):
        if not any(c.segment == seg.name for c in robot.cables):
            problems.append(
                (("robot", "segments", s, "name"), "no cable ends in this segment", seg.name)
            )

    hb_ms = cfg.can.master_heartbeat_ms
    for i, drive in enumerate(cfg.drives):
        # CiA 301: the consumer time must outlast the producer period, with room for one lost
        # heartbeat, or a healthy controller faults its own drives.
        if drive.heartbeat_consumer_ms < 2 * hb_ms:
            problems.append(
                (
                    ("drives", i, "heartbeat_consumer_ms"),
                    f"below twice can.master_heartbeat_ms ({hb_ms} ms): a healthy controller"
                    " would fault the drive",
                    drive.heartbeat_consumer_ms,
                )
            )
    unique(cfg.drives, "name", ("drives",))
    unique(cfg.drives, "node_id", ("drives",))
    driven = unique(cfg.drives, "cable", ("drives",))
    for i, drive in enumerate(cfg.drives):
        if drive.cable not in cables:
            problems.append((("drives", i, "cable"), "no cable of that name", drive.cable))
        if drive.node_id == cfg.can.master_node_id:
            problems.append(
                (("drives", i, "node_id"), "clashes with can.master_node_id", drive.node_id)
            )
    for i, cable in enumerate(robot.cables):
        if cable.name not in driven:
            problems.append(
                (("robot", "cables", i, "name"), "no drive pulls this cable", cable.name)
            )

    lc = cfg.sensors.load_cells
    if lc is not None:
        where: KeyPath = ("sensors", "load_cells", "cells")
        unique(lc.cells, "cable", where)
        if lc.protocol == "modbus_rtu":
            unique(lc.cells, "slave", where)
        elif len(lc.cells) > 1:
            problems.append((where, "the ASCII protocol carries one cell per port", len(lc.cells)))
        for i, cell in enumerate(lc.cells):
            if cell.cable not in cables:
                problems.append(((*where, i, "cable"), "no cable of that name", cell.cable))
    problems.extend(check_design(cfg))
    return problems
