"""Trajectory files and request rows: parse CSV, YAML and ``[t_s, θ1, φ1, ...]`` rows into a
validated :class:`~cdcr_ctl.control.trajectory.core.Trajectory`.

CSV: comment lines start with ``#``; header ``t_s,seg1_theta_rad,seg1_phi_rad,seg2_theta_rad,...``
(exactly these names, segments in order); one row per sample.

YAML::

    name: demo            # optional
    n_segments: 1         # optional; checked against the rows and the rig
    samples:              # a list of samples (the whole file may also be just this list)
      - t_s: 0.0
        segments: [[0.0, 0.0]]        # [theta_rad, phi_rad] per segment, base to tip
      - {t_s: 5.0, segments: [[1.5708, 0.0]]}

Both are validated: times finite, >= 0 and strictly increasing; θ, φ finite, θ >= 0; segment
count equal to the rig's; θ within the bend limit; bending-vector rate within the rate limit.
Errors are :class:`~cdcr_ctl.errors.ConfigError` naming the file, the line and the column/field.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cdcr_ctl.control.trajectory.core import Trajectory
from cdcr_ctl.errors import ConfigError


# =========================================================================== loaders
def _rows_locator(n: int, i: int, what: str) -> str:
    j = 0 if i < 0 else 2 * i + 1 + (what == "phi")
    return f"samples[{n}]" if what == "segments" else f"samples[{n}][{j}]"


def _float(value: Any) -> float | None:
    """A finite-or-not float from a real number (not a bool); None for anything else."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def from_samples(
    samples: Sequence[Sequence[float]],
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
    source: str = "samples",
    name: str = "",
) -> Trajectory:
    """Trajectory from rows ``[t_s, seg1_theta, seg1_phi, ...]`` (the daemon's request form).

    Errors name ``source`` and ``samples[n][j]``.
    """
    if isinstance(samples, np.ndarray):
        samples = samples.tolist()
    if not isinstance(samples, Sequence) or isinstance(samples, str | bytes) or not samples:
        raise ConfigError(source, "samples", "need a non-empty list of samples")
    width = None
    values: list[list[float]] = []
    for n, row in enumerate(samples):
        if not isinstance(row, Sequence) or isinstance(row, str | bytes):
            raise ConfigError(source, f"samples[{n}]", "a sample is a list [t_s, theta, phi, ...]")
        if width is None:
            width = len(row)
            if width < 3 or width % 2 == 0:
                raise ConfigError(
                    source,
                    f"samples[{n}]",
                    f"{width} values: need t_s then (theta, phi) per segment",
                    width,
                )
        if len(row) != width:
            raise ConfigError(source, f"samples[{n}]", f"{len(row)} values, the first had {width}")
        vals = []
        for j, v in enumerate(row):
            f = _float(v)
            if f is None or not math.isfinite(f):
                raise ConfigError(source, f"samples[{n}][{j}]", "not a finite number", v)
            vals.append(f)
        values.append(vals)
    arr = np.array(values)
    traj = Trajectory(
        arr[:, 0], arr[:, 1:].reshape(len(arr), -1, 2), name, source, locate=_rows_locator
    )
    return traj.validate(n_segments, bend_limit_rad, max_rate_rad_s)


def load_trajectory(
    path: str | Path,
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
) -> Trajectory:
    """Load a ``.csv`` or ``.yaml``/``.yml`` trajectory file and validate it (module docstring)."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".csv":
        return load_csv(p, n_segments, bend_limit_rad, max_rate_rad_s)
    if suffix in (".yaml", ".yml"):
        return load_yaml(p, n_segments, bend_limit_rad, max_rate_rad_s)
    raise ConfigError(str(p), "", "trajectory files are .csv, .yaml or .yml")


def _read_text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(str(path), "", f"cannot read: {exc.strerror or exc}") from exc
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(str(path), f"line {line}", "not UTF-8 text") from exc


_CSV_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$", re.ASCII)


def load_csv(
    path: str | Path,
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
) -> Trajectory:
    """Load a CSV trajectory (header ``t_s,seg1_theta_rad,seg1_phi_rad,...``) and validate it.

    Errors are :class:`ConfigError` with key ``line L, <column>``.
    """
    p = Path(path)
    src = str(p)
    text = _read_text(p)
    header: list[str] | None = None
    values: list[list[float]] = []
    lines: list[int] = []
    for ln, raw in enumerate(text.split("\n"), start=1):
        line = raw.rstrip("\r").strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if header is None:
            header = _csv_header(src, ln, fields)
            continue
        if len(fields) != len(header):
            raise ConfigError(src, f"line {ln}", f"{len(fields)} fields for {len(header)} columns")
        row = []
        for name, field in zip(header, fields, strict=True):
            if not _CSV_NUMBER.match(field):
                raise ConfigError(src, f"line {ln}, {name}", "not a number", field)
            row.append(float(field))
        values.append(row)
        lines.append(ln)
    if header is None:
        raise ConfigError(src, "", "no header line (t_s,seg1_theta_rad,seg1_phi_rad,...)")
    if not values:
        raise ConfigError(src, "", "no samples after the header")
    arr = np.array(values)

    def locate(n: int, i: int, what: str) -> str:
        if what == "segments":
            return "header"
        col = "t_s" if i < 0 else f"seg{i + 1}_{what}_rad"
        return f"line {lines[n]}, {col}"

    traj = Trajectory(arr[:, 0], arr[:, 1:].reshape(len(arr), -1, 2), p.stem, src, locate)
    return traj.validate(n_segments, bend_limit_rad, max_rate_rad_s)


def _csv_header(src: str, ln: int, fields: list[str]) -> list[str]:
    if len(fields) < 3 or len(fields) % 2 == 0:
        raise ConfigError(
            src,
            f"line {ln}",
            "header must be t_s then seg{i}_theta_rad, seg{i}_phi_rad per segment",
            ",".join(fields)[:200],
        )
    expected = ["t_s"]
    for i in range(1, (len(fields) - 1) // 2 + 1):
        expected += [f"seg{i}_theta_rad", f"seg{i}_phi_rad"]
    for j, (got, want) in enumerate(zip(fields, expected, strict=True), start=1):
        if got != want:
            raise ConfigError(src, f"line {ln}, column {j}", f"expected {want!r}", got[:200])
    return expected


def _yaml_node_line(node: Any, path: Sequence[str | int]) -> int | None:
    """1-based line of the YAML node at ``path`` (keys and indices), or of its deepest parent."""
    line = node.start_mark.line + 1
    for part in path:
        nxt = None
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                if isinstance(k, yaml.ScalarNode) and k.value == str(part):
                    nxt = v
                    break
        elif (
            isinstance(node, yaml.SequenceNode)
            and isinstance(part, int)
            and 0 <= part < len(node.value)
        ):
            nxt = node.value[part]
        if nxt is None:
            return line
        node = nxt
        line = node.start_mark.line + 1
    return line


def load_yaml(
    path: str | Path,
    n_segments: int | None = None,
    bend_limit_rad: float | Sequence[float] | None = None,
    max_rate_rad_s: float | Sequence[float] | None = None,
) -> Trajectory:
    """Load a YAML trajectory (module docstring) and validate it.

    Errors are :class:`ConfigError` with key ``samples[n].segments[i][0] (line L)``.
    """
    p = Path(path)
    src = str(p)
    text = _read_text(p)
    loader = None
    try:
        loader = yaml.SafeLoader(text)
        root = loader.get_single_node()
        doc = loader.construct_document(root) if root is not None else None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ConfigError(src, where, f"YAML syntax error: {problem}") from exc
    except RecursionError as exc:
        raise ConfigError(src, "", "YAML nested too deeply") from exc
    finally:
        if loader is not None:
            loader.dispose()

    def key(path_: Sequence[str | int]) -> str:
        text_ = ""
        for part in path_:
            text_ += f"[{part}]" if isinstance(part, int) else ("." if text_ else "") + part
        line = _yaml_node_line(root, path_) if root is not None else None
        return f"{text_} (line {line})" if line else text_

    name = p.stem
    base: list[str | int] = []
    declared: int | None = None
    if isinstance(doc, Mapping):
        for k in doc:
            if k not in ("name", "n_segments", "samples"):
                raise ConfigError(src, key([str(k)]), "unknown key (name, n_segments, samples)")
        if "name" in doc:
            if not isinstance(doc["name"], str):
                raise ConfigError(src, key(["name"]), "must be text", doc["name"])
            name = doc["name"]
        if "n_segments" in doc:
            declared = doc["n_segments"]
            if isinstance(declared, bool) or not isinstance(declared, int) or declared < 1:
                raise ConfigError(src, key(["n_segments"]), "must be an integer >= 1", declared)
        if "samples" not in doc:
            raise ConfigError(src, "samples", "missing")
        samples = doc["samples"]
        base = ["samples"]
    else:
        samples = doc
    if not isinstance(samples, list) or not samples:
        raise ConfigError(src, key(base) or "samples", "need a non-empty list of samples")

    S = declared
    ts: list[float] = []
    psis: list[list[list[float]]] = []
    for n, item in enumerate(samples):
        here: list[str | int] = [*base, n]
        if not isinstance(item, Mapping):
            raise ConfigError(src, key(here), "a sample is {t_s: ..., segments: [[theta, phi]]}")
        for k in item:
            if k not in ("t_s", "segments"):
                raise ConfigError(src, key([*here, str(k)]), "unknown key (t_s, segments)")
        if "t_s" not in item or "segments" not in item:
            raise ConfigError(src, key(here), "needs t_s and segments")
        t = _float(item["t_s"])
        if t is None or not math.isfinite(t):
            raise ConfigError(src, key([*here, "t_s"]), "not a finite number", item["t_s"])
        segs = item["segments"]
        if not isinstance(segs, list) or not segs:
            raise ConfigError(
                src, key([*here, "segments"]), "need a list of [theta_rad, phi_rad] per segment"
            )
        if S is None:
            S = len(segs)
        if len(segs) != S:
            what = "n_segments" if declared is not None else "the first sample"
            raise ConfigError(
                src, key([*here, "segments"]), f"{len(segs)} segment(s), {what} says {S}"
            )
        row = []
        for i, pair in enumerate(segs):
            if not isinstance(pair, list) or len(pair) != 2:
                raise ConfigError(
                    src, key([*here, "segments", i]), "a segment is [theta_rad, phi_rad]"
                )
            vals = []
            for j, v in enumerate(pair):
                f = _float(v)
                if f is None or not math.isfinite(f):
                    raise ConfigError(src, key([*here, "segments", i, j]), "not a finite number", v)
                vals.append(f)
            row.append(vals)
        ts.append(t)
        psis.append(row)

    def locate(n: int, i: int, what: str) -> str:
        if what == "segments":
            return key([*base, n, "segments"])
        if i < 0:
            return key([*base, n, "t_s"])
        return key([*base, n, "segments", i, 0 if what == "theta" else 1])

    traj = Trajectory(ts, psis, name, src, locate)
    return traj.validate(n_segments, bend_limit_rad, max_rate_rad_s)
