"""The ``[content]`` section: defaults, bounds and errors naming key and line."""

from __future__ import annotations

import pytest

from grassd.daemon.content.config import ContentConfig, SacnConfig
from grassd.daemon.core.config.settings import default_config_text, parse_config
from grassd.daemon.core.errors import ConfigError


def _with(section: str):
    return parse_config(default_config_text() + "\n" + section, source="t.toml")


def test_without_section_no_content():
    assert parse_config(default_config_text()).content is None


def test_defaults_written_once_on_the_dataclasses(tmp_path):
    cfg = _with("[content]\nenabled = true\n")
    c = cfg.content
    assert c == ContentConfig(enabled=True)
    assert (c.fps, c.hold_s, c.map, c.sacn.port, c.artnet.port) == (30, 1.0, "nearest_de00",
                                                                    5568, 6454)
    assert c.sacn == SacnConfig() and c.idle is None and c.playlist == ()


def test_playlist_and_receivers_parsed():
    cfg = _with('[content]\nidle = "/srv/idle.png"\n[content.artnet]\nnet = 1\nsubnet = 2\n'
                'universe = 3\n[[content.playlist]]\nfile = "/srv/a.gif"\nduration_s = 5\n'
                'hours = [22, 6]\n')
    c = cfg.content
    assert c.artnet.port_address == (1 << 8) | (2 << 4) | 3
    (e,) = c.playlist
    assert (str(e.file), e.duration_s, e.start_hour, e.end_hour) == ("/srv/a.gif", 5.0, 22, 6)
    assert e.plays_at(23) and e.plays_at(2) and not e.plays_at(12)
    assert str(c.idle) == "/srv/idle.png"


@pytest.mark.parametrize("section,key", [
    ("[content]\nfps = 61\n", "content.fps"),
    ("[content]\nfps = 0\n", "content.fps"),
    ("[content]\nmap = \"red\"\n", "content.map"),
    ("[content]\nhold_s = -1\n", "content.hold_s"),
    ("[content]\nfirst = \"middle\"\n", "content.first"),
    ("[content.sacn]\nuniverse = 0\n", "content.sacn.universe"),
    ("[content.sacn]\nstart_channel = 513\n", "content.sacn.start_channel"),
    ("[content.artnet]\nsubnet = 16\n", "content.artnet.subnet"),
    ("[content.artnet]\nport = 5568\n", "content.artnet.port"),
    ("[content]\ncolour = 1\n", "content.colour"),
    ("[[content.playlist]]\nfile = \"a.png\"\nhours = [5, 5]\n", "content.playlist[0].hours"),
])
def test_bad_values_name_key_and_line(section, key):
    with pytest.raises(ConfigError) as err:
        _with(section)
    assert err.value.key == key
    assert err.value.line is not None and err.value.line > default_config_text().count("\n")


def test_check_config_summarises_content(tmp_path):
    from click.testing import CliRunner

    from grassd.daemon.cli.main import main

    conf = tmp_path / "grassd.toml"
    conf.write_text(default_config_text() + '\n[content]\nenabled = true\nfps = 24\n'
                    '[content.artnet]\nenabled = false\n[[content.playlist]]\nfile = "a.png"\n')
    out = CliRunner().invoke(main, ["check-config", "--config", str(conf)])
    assert out.exit_code == 0, out.output
    line = next(s for s in out.output.splitlines() if s.strip().startswith("content:"))
    assert "on, 24 fps" in line and "sACN 127.0.0.1:5568 from universe 1" in line
    assert "Art-Net" not in line and "1 playlist entry" in line
    assert f"warning: content picture {tmp_path / 'a.png'} does not exist" in out.output
    (tmp_path / "a.png").write_bytes(b"")
    out = CliRunner().invoke(main, ["check-config", "--config", str(conf)])
    assert "does not exist" not in out.output
