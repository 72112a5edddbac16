"""docs/reference/config.md is the schema's: regenerated from cdcr_ctl/config and compared.

A key added, removed or changed in the schema (type, default, bounds, description) without
regenerating the page fails here, naming the key; so does a key the schema leaves undescribed.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from scriptload import load_script

ROOT = Path(__file__).resolve().parents[2]


def _generator():
    return load_script("config_reference")


def test_page_is_the_schemas():
    gen = _generator()
    text, missing = gen.build()
    assert not missing, f"keys without a description in the schema: {missing}"
    page = gen.PAGE.read_text()
    assert page == text, gen.diff_keys(page, text)


def test_a_schema_change_shows_as_a_named_key(monkeypatch):
    """The check sees a change the page does not show: a new key, and a changed bound."""
    from typing import Annotated

    from cdcr_ctl.config.control import LiveViewConfig

    gen = _generator()
    page = gen.PAGE.read_text()
    real = gen.fields_of
    fields = real(LiveViewConfig)
    fields["burst_hz"] = Field(default=5.0, description="Made-up key for the test.")
    fields["burst_hz"].annotation = Annotated[float, Field(gt=0, le=9)]
    monkeypatch.setattr(
        gen, "fields_of", lambda cls: fields if cls is LiveViewConfig else real(cls)
    )
    text, _ = gen.build()
    assert text != page
    message = gen.diff_keys(page, text)
    assert "key in the schema, not on the page: live.burst_hz" in message

    fields = real(LiveViewConfig)
    port = fields["port"]
    changed = Field(default=port.default, ge=1, le=65535)
    changed.annotation = int
    fields["port"] = changed
    text, _ = gen.build()
    message = gen.diff_keys(page, text)
    assert "key differs: live.port" in message
    assert "≥ 1" in message
