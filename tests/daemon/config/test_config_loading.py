"""Config loading and validation: errors name the key and the line of the file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from grassd.daemon.core.config.schema import LineLocator
from grassd.daemon.core.config.settings import (
    default_config_text,
    load_config,
    load_default_config,
    parse_config,
    parse_pixel_ranges,
)
from grassd.daemon.core.errors import ConfigError

GRASSD = str(Path(sys.executable).parent / "grassd")

GOOD = """\
state_dir = "state"

[site]
latitude = 52.5
longitude = 13.4
timezone = "Europe/Berlin"

[display]
rows = 2
cols = 4

[[controllers]]
port = "/dev/ttyUSB0"
baud = 57_600
pixels = "0-3"

[[controllers]]
port = "/dev/ttyUSB0"
address = 2
baud = 57600
pixels = "4-7"

[[viewpoints]]
h_cm = 170
d_m = 2

[light]
inbox = "in"

[simulation]
lengths = [0.0, 5.0, 10.0, 20.0]
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "grassd.toml"
    p.write_text(text)
    return p


def test_good_config_parses_to_frozen_dataclasses(tmp_path):
    cfg = load_config(write(tmp_path, GOOD))
    assert cfg.site.timezone == "Europe/Berlin"
    assert cfg.display.pixel_count == 8
    assert [c.address for c in cfg.controllers] == [1, 2]
    assert cfg.controllers[1].baud == 57600
    assert cfg.controllers[0].pixels == ((0, 3),)
    assert cfg.viewpoints[0].h_cm == 170.0 and isinstance(cfg.viewpoints[0].h_cm, float)
    assert cfg.state_dir == tmp_path / "state"          # relative to the config file
    assert cfg.light.inbox == tmp_path / "state" / "in"  # relative inbox lies in state_dir
    assert cfg.simulation.lengths_mm == (0.0, 5.0, 10.0, 20.0)
    assert cfg.calibration.target_de00 == 0.5 and cfg.calibration.max_rounds == 3
    assert cfg.display.pixel["green_max_mm"] == 20.0
    with pytest.raises(AttributeError):
        cfg.site.latitude = 0.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        cfg.display.pixel["size_mm"] = 1.0  # type: ignore[index]


def _err(tmp_path, text) -> ConfigError:
    with pytest.raises(ConfigError) as ei:
        load_config(write(tmp_path, text))
    return ei.value


def _line_of(text: str, needle: str) -> int:
    return next(i for i, ln in enumerate(text.splitlines(), 1) if needle in ln)


@pytest.mark.parametrize(
    ("old", "new", "key", "needle", "words"),
    [
        ('baud = 57600', 'baud = 57600\nspeed = 3', "controllers[1].speed", "speed = 3",
         "unknown key"),
        ('baud = 57600', 'baud = "fast"', "controllers[1].baud", 'baud = "fast"', "integer"),
        ('h_cm = 170', 'h_cm = true', "viewpoints[0].h_cm", "h_cm = true", "number"),
        ('latitude = 52.5', 'latitude = 95.0', "site.latitude", "latitude = 95.0", "between"),
        ('timezone = "Europe/Berlin"', 'timezone = "Mars/Olympus"', "site.timezone",
         "Mars/Olympus", "time zone"),
        ('pixels = "4-7"', 'pixels = "3-7"', "controllers[1].pixels", 'pixels = "3-7"', "overlap"),
        ('pixels = "4-7"', 'pixels = "4-9"', "controllers[1].pixels", 'pixels = "4-9"',
         "does not exist"),
        # one controller listing a pixel twice (overlaps within its own list)
        ('pixels = "4-7"', 'pixels = "4-6,5-7"', "controllers[1].pixels", 'pixels = "4-6,5-7"',
         "pixel 5 is listed twice"),
        ('pixels = "4-7"', 'pixels = "4-7,6"', "controllers[1].pixels", 'pixels = "4-7,6"',
         "pixel 6 is listed twice"),
        ('address = 2', 'address = 1', "controllers[1].address", "address = 1", "already used"),
        # one RS-485 bus, one line speed: the fleet opens a shared port once, at one baud
        ('baud = 57600', 'baud = 9600', "controllers[1].baud", "baud = 9600", "same bus"),
        # the wire protocol answers addresses 1..247 only (0 and 248..255 are reserved)
        ('address = 2', 'address = 0', "controllers[1].address", "address = 0", "between 1 and"),
        ('address = 2', 'address = 248', "controllers[1].address", "address = 248",
         "between 1 and"),
        ('inbox = "in"', 'inbox = "in"\nlux = "sky"', "light.lux", 'lux = "sky"', "one of"),
        ('inbox = "in"', 'inbox = "in"\nlux = "modbus"', "light.lux", 'lux = "modbus"',
         "[light.modbus]"),
        ('lengths = [0.0, 5.0, 10.0, 20.0]', 'lengths = [0.0, 5.0, 4.0]', "simulation.lengths",
         "lengths = [0.0, 5.0, 4.0]", "increasing"),
        ('cols = 4', 'cols = 4\n[display.pixel]\nslit_width_mm = -1.0',
         "display.pixel.slit_width_mm", "slit_width_mm = -1.0", ">= 0"),
        ('cols = 4', 'cols = 4\n[display.pixel]\nslit_count = 9', "display.pixel",
         "[display.pixel]", "do not fit"),
        ('cols = 4', 'cols = 4\n[display.pixel]\ngreen_srgb = [1, 2]', "display.pixel.green_srgb",
         "green_srgb = [1, 2]", "array of 3 numbers"),
        # neither trigger: bundles in the inbox would never be picked up
        ('[0.0, 5.0, 10.0, 20.0]', '[0.0, 5.0, 10.0, 20.0]\n[schedule]\ninterval_s = 0\n'
         'on_new_bundle = false', "schedule.on_new_bundle", "on_new_bundle = false",
         "never be picked up"),
        ('[0.0, 5.0, 10.0, 20.0]', '[0.0, 5.0, 10.0, 20.0]\n[calibration]\nmax_rounds = 0',
         "calibration.max_rounds",
         "max_rounds = 0", "between 1 and 10"),
    ],
)
def test_bad_values_name_key_and_line(tmp_path, old, new, key, needle, words):
    text = GOOD.replace(old, new, 1)
    assert text != GOOD
    err = _err(tmp_path, text)
    assert err.key == key
    assert err.line == _line_of(text, needle), str(err)
    assert words in str(err)
    assert f"grassd.toml:{err.line}: {key}:" in str(err)


def test_missing_required_key_points_at_table_header(tmp_path):
    text = GOOD.replace("longitude = 13.4\n", "")
    err = _err(tmp_path, text)
    assert err.key == "site.longitude" and "required" in str(err)
    assert err.line == _line_of(text, "[site]")


def test_unknown_top_level_table(tmp_path):
    text = GOOD + "\n[extra]\nx = 1\n"
    err = _err(tmp_path, text)
    assert err.key == "extra" and err.line == _line_of(text, "[extra]")


def test_modbus_rtu_needs_serial_port_and_float_needs_two_words(tmp_path):
    base = GOOD.replace('inbox = "in"',
                        'inbox = "in"\nlux = "modbus"\n[light.modbus]\nmode = "rtu"')
    err = _err(tmp_path, base)
    assert err.key == "light.modbus.serial_port"
    text = base.replace('mode = "rtu"', 'mode = "tcp"\nvalue_type = "float"\nwords = 1')
    err = _err(tmp_path, text)
    assert err.key == "light.modbus.words" and err.line == _line_of(text, "words = 1")
    rtu = 'mode = "rtu"\nserial_port = "/dev/ttyAMA0"\nfunction_code = 3\nword_order = "little"'
    ok = load_config(write(tmp_path, base.replace('mode = "rtu"', rtu)))
    m = ok.light.modbus
    got = (m.mode, m.serial_port, m.function_code, m.word_order)
    assert got == ("rtu", "/dev/ttyAMA0", 3, "little")


def test_syntax_error_reports_line(tmp_path):
    text = GOOD.replace("rows = 2", "rows = = 2")
    err = _err(tmp_path, text)
    assert err.line == _line_of(text, "rows = = 2")
    assert "syntax" in str(err)


def test_missing_file_is_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")


def test_locator_handles_nested_and_arrays():
    text = "a = 1\n[x]\nb = 2\n[[t]]\nc = 3\n[[t]]\nc = 4\n[t.sub]\nd = 5\n\"q k\" = 6\n"
    loc = LineLocator(text)
    assert loc.line_of(("a",)) == 1
    assert loc.line_of(("x", "b")) == 3
    assert loc.line_of(("t", 0, "c")) == 5
    assert loc.line_of(("t", 1, "c")) == 7
    assert loc.line_of(("t", 1, "sub", "d")) == 9
    assert loc.line_of(("t", 1, "sub", "q k")) == 10
    assert loc.line_of(("t", 1, "sub", "missing")) == 8


def test_pixel_ranges():
    assert parse_pixel_ranges("all", 5) == ((0, 4),)
    assert parse_pixel_ranges("1,3-4", 5) == ((1, 1), (3, 4))
    for bad in ("4-2", "x", "0-5"):
        with pytest.raises(ValueError):
            parse_pixel_ranges(bad, 5)
    assert parse_pixel_ranges("3-4,0-2", 5) == ((3, 4), (0, 2))  # any order, touching is fine
    for twice, pixel in (("0-3,2-4", 2), ("1,1", 1), ("3-4,0-3", 3), ("0-4,2", 2)):
        with pytest.raises(ValueError, match=f"pixel {pixel} is listed twice"):
            parse_pixel_ranges(twice, 5)


def test_embedded_default_is_valid_and_env_dirs(monkeypatch, tmp_path):
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "st"))
    monkeypatch.setenv("GRASSD_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("RUNTIME_DIRECTORY", str(tmp_path / "run"))
    cfg = load_default_config()
    assert "[[controllers]]" in default_config_text()
    assert cfg.state_dir == tmp_path / "st"
    assert cfg.cache_dir == tmp_path / "cache"
    assert cfg.control_socket == tmp_path / "run" / "control.sock"
    assert cfg.light.inbox == tmp_path / "st" / "inbox"
    moved = cfg.with_state_dir(tmp_path / "other")
    assert moved.light.inbox == tmp_path / "other" / "inbox"
    assert moved.cache_dir == tmp_path / "cache"  # from the environment: not moved
    assert all(c.port.startswith("/dev/serial/by-id/") for c in cfg.controllers)


def test_parse_config_is_deterministic():
    assert parse_config(GOOD, base_dir=Path("/x")) == parse_config(GOOD, base_dir=Path("/x"))


def test_check_config_cli(tmp_path):
    good = write(tmp_path, GOOD)
    r = subprocess.run([GRASSD, "check-config", "--config",
                        str(good)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "OK" in r.stdout and "addr 2 @ 57600" in r.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace("h_cm = 170", "h_cm = 170\ncolour = 1"))
    r = subprocess.run([GRASSD, "check-config", "--config",
                        str(bad)], capture_output=True, text=True)
    assert r.returncode == 2
    line = _line_of(bad.read_text(), "colour = 1")
    assert r.stderr.strip() == (f"grassd: error: {bad}:{line}: viewpoints[0].colour: unknown key "
                                "(allowed here: d_m, h_cm, theta_deg, weight)")


def test_settings_the_daemon_does_not_act_on_are_reported(tmp_path):
    """grassd run honours [tables] granularity and [audience] (no warning any more); a setting
    that means nothing in its context ([tables] eye = "pixel" with [audience]) is reported by
    check-config instead of being silently ignored."""
    from click.testing import CliRunner

    from grassd.daemon.cli.main import main
    from grassd.daemon.core.config.settings import default_config_text

    path = tmp_path / "grassd.toml"
    path.write_text(default_config_text() + '\n[tables]\ngranularity = "controller"\n')
    res = CliRunner().invoke(main, ["check-config", "--config", str(path)])
    assert res.exit_code == 0, res.output
    assert "warning" not in res.output
    path.write_text(default_config_text() + '\n[tables]\ngranularity = "pixel"\neye = "pixel"\n'
                    '[audience]\npolygon = [[-1, -3], [1, -3], [1, -1]]\nh_cm = [150, 180]\n')
    res = CliRunner().invoke(main, ["check-config", "--config", str(path)])
    assert res.exit_code == 0, res.output
    assert "warning: tables.eye = 'pixel' is ignored with [audience]" in res.output


def test_bundle_limits_of_the_template_are_the_defaults_and_are_checked():
    """default.toml states the caps on a bundle ([light.limits]); they must be the dataclass
    defaults (written once there), and a cap out of bounds names its key and line."""
    from grassd.daemon.core.config.limits import DEFAULT_LIMITS
    from grassd.daemon.core.config.settings import parse_config

    text = default_config_text()
    assert "[light.limits]" in text
    assert load_default_config().light.limits == DEFAULT_LIMITS
    with pytest.raises(ConfigError, match=r":\d+: light\.limits\.file_mib: must be between"):
        parse_config(text.replace("file_mib = 512", "file_mib = 0"))
    no_table = text.replace("[light.limits]", "[unused_limits_table]")
    cut = no_table[:no_table.index("[unused_limits_table]")] + no_table[
        no_table.index("[light.modbus]"):]
    assert parse_config(cut).light.limits == DEFAULT_LIMITS  # the table may be left out
