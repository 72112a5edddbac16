"""Key paths into a rig config (``robot.cables[1].segment``): how every config error names its
key. A leaf module, so the schema's sections and the loader can both use it."""

from __future__ import annotations

KeyPath = tuple[str | int, ...]


def format_key(path: KeyPath) -> str:
    """Render a key path as ``robot.cables[1].segment``."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out
