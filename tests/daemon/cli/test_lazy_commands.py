"""``grassd``'s sub-commands load on first use (fast start-up), and what the group's help
says of each without loading it is what the command itself says."""

from __future__ import annotations

import subprocess
import sys

import click
import pytest

from grassd.daemon.cli.lazy import LazyCommand, LazyCommands, LazyGroup
from grassd.daemon.cli.main import COMMANDS


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_each_stored_summary_shortens_as_the_loaded_command_help(name):
    """At every width the group's help may give it, the stored summary shortens to the
    loaded command's own short help, and the command has the name it is listed under."""
    spec = COMMANDS[name]
    command = spec.load()
    assert command.name == name
    assert not command.hidden and command.short_help is None
    stand_in = click.Command(name, help=spec.summary)
    for width in range(10, 200):
        assert stand_in.get_short_help_str(width) == command.get_short_help_str(width), width


def test_the_mapping_loads_a_module_only_when_its_command_is_looked_up():
    """Membership, listing and length import nothing; a look-up imports the one module; a
    name that is not there is a KeyError."""
    code = """
import sys
from grassd.daemon.cli.main import main
names = sorted(main.commands)
assert "status" in main.commands and "nope" not in main.commands and len(main.commands) == 18
before = sorted(m for m in sys.modules if m.startswith("grassd.daemon.cli."))
main.commands["history"]
after = sorted(m for m in sys.modules if m.startswith("grassd.daemon.cli."))
print(names == sorted(set(names)), before, sorted(set(after) - set(before)))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == [
        "True", "['grassd.daemon.cli.lazy',", "'grassd.daemon.cli.main']",
        "['grassd.daemon.cli.run']"], proc.stdout


def test_a_missing_or_wrong_target_is_an_error():
    commands = LazyCommands({"x": LazyCommand("grassd.daemon.cli.lazy", "LazyGroup", "X.")})
    with pytest.raises(TypeError, match="not a click command"):
        commands["x"]
    with pytest.raises(KeyError):
        commands["y"]


def test_added_and_removed_commands_behave_as_in_a_plain_group():
    @click.command("hello")
    def hello() -> None:
        """Say hello."""

    group = LazyGroup("g", lazy={"run": COMMANDS["run"]})
    group.add_command(hello)
    assert list(group.commands) == ["hello", "run"] and len(group.commands) == 2
    del group.commands["run"]
    assert "run" not in group.commands
    assert group.commands.pending("hello") is None
    with pytest.raises(KeyError):
        del group.commands["run"]
