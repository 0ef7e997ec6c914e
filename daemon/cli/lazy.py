"""A click group whose sub-commands are imported only when one is used (fast start-up).

Each sub-command module imports what its commands need (the renderer, colour-science, numpy
...), which takes seconds. :class:`LazyGroup` names its sub-commands with :class:`LazyCommand`
(module, attribute and the first paragraph of its help) and keeps them in
:class:`LazyCommands`, a mapping that imports a command's module on first look-up. Click's own
:class:`click.Group` code then works unchanged (``get_command``, ``list_commands``, shell
completion, ``group.commands[name]``); only the group's help, which lists every sub-command, is
written from the stored summaries, so ``grassd --help`` imports no sub-command module. A test
(tests/daemon/cli/test_lazy_commands.py) checks each summary against the loaded command's help.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping, MutableMapping
from dataclasses import dataclass
from typing import Any

import click


@dataclass(frozen=True)
class LazyCommand:
    """Where a sub-command lives and what the group's help says of it.

    ``summary`` is the first paragraph of the command's help (its docstring) on one line;
    click shortens it for the group's help as it would the command's own help.
    """

    module: str  #: dotted module that defines the command
    attr: str  #: name of the :class:`click.Command` in that module
    summary: str  #: first paragraph of the command's help

    def load(self) -> click.Command:
        """Import the module and return the command (a :class:`click.Command`)."""
        command = getattr(importlib.import_module(self.module), self.attr)
        if not isinstance(command, click.Command):
            raise TypeError(f"{self.module}.{self.attr} is not a click command")
        return command


class LazyCommands(MutableMapping[str, click.Command]):
    """Name -> sub-command; a :class:`LazyCommand` is loaded on its first look-up. Membership,
    iteration and length never import anything."""

    def __init__(self, lazy: Mapping[str, LazyCommand]) -> None:
        self._lazy = dict(lazy)
        self._loaded: dict[str, click.Command] = {}

    def __getitem__(self, name: str) -> click.Command:
        if name not in self._loaded:
            self._loaded[name] = self._lazy.pop(name).load()  # KeyError: no such command
        return self._loaded[name]

    def __setitem__(self, name: str, command: click.Command) -> None:
        self._lazy.pop(name, None)
        self._loaded[name] = command

    def __delitem__(self, name: str) -> None:
        if self._lazy.pop(name, None) is None:
            del self._loaded[name]

    def __contains__(self, name: object) -> bool:
        return name in self._lazy or name in self._loaded

    def __iter__(self) -> Iterator[str]:
        return iter([*self._loaded, *self._lazy])

    def __len__(self) -> int:
        return len(self._loaded) + len(self._lazy)

    def pending(self, name: str) -> LazyCommand | None:
        """The not yet loaded command ``name``, else None (loaded, or no such command)."""
        return self._lazy.get(name)


class LazyGroup(click.Group):
    """A :class:`click.Group` whose sub-commands named in ``lazy`` load on first use."""

    def __init__(self, *args: Any, lazy: Mapping[str, LazyCommand] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        commands = LazyCommands(lazy or {})
        commands.update(self.commands)
        self.commands = commands  # type: ignore[assignment]  # a MutableMapping, as click uses it

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """The "Commands" section as :meth:`click.Group.format_commands` writes it, from the
        stored summaries of the sub-commands not loaded yet."""
        rows: list[tuple[str, click.Command]] = []
        for name in self.list_commands(ctx):
            pending = self.commands.pending(name)  # type: ignore[attr-defined]
            command = (click.Command(name, help=pending.summary) if pending is not None
                       else self.get_command(ctx, name))
            if command is not None and not command.hidden:
                rows.append((name, command))
        if rows:
            limit = formatter.width - 6 - max(len(name) for name, _ in rows)
            with formatter.section("Commands"):
                formatter.write_dl([(name, command.get_short_help_str(limit))
                                    for name, command in rows])
