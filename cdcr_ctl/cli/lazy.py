"""A click group whose subcommands are imported when one is used (click's documented way, "Complex
Applications": lazily loading subcommands).

Every ``cdcr-ctl`` process pays for the modules it imports: ``cdcr-ctl status`` need not import
the identification's scipy.stats, nor ``cdcr-ctl daemon`` the terminal page's rich. The group
knows each command by name and ``"module.attribute"``; a command's module is imported when the
command runs, or when the group's ``--help`` lists it (the listing needs each command's short
help, so the command modules import their heavy dependencies inside the commands, not at the top).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any

import click


class LazyGroup(click.Group):
    """A :class:`click.Group` with ``lazy_subcommands``: command name -> ``"module.attribute"``
    of a :class:`click.Command`, imported on first use."""

    def __init__(
        self,
        *args: Any,
        lazy_subcommands: Mapping[str, str] | None = None,
        shared_options: Callable[[click.Command], Any] | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(*args, **kwargs)
        self.lazy_subcommands = dict(lazy_subcommands or {})
        #: Called once on each command when it is loaded (to add the group's shared options).
        self.shared_options = shared_options

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted({*super().list_commands(ctx), *self.lazy_subcommands})

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.lazy_subcommands:
            return self.load(cmd_name)
        return super().get_command(ctx, cmd_name)

    def load(self, cmd_name: str) -> click.Command:
        """Import the command ``cmd_name`` (cached by the import system after the first time)."""
        module_name, _, attr = self.lazy_subcommands[cmd_name].rpartition(".")
        command = getattr(importlib.import_module(module_name), attr)
        if not isinstance(command, click.Command):
            raise TypeError(f"{module_name}.{attr} is not a click command")
        if self.shared_options is not None and not getattr(command, "_shared_added", False):
            self.shared_options(command)
            command._shared_added = True  # type: ignore[attr-defined]
        return command


__all__ = ["LazyGroup"]
