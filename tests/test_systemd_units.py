"""systemd units checked with Debian's systemd tools (systemd 252 on Debian 12)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "systemd" / "grassd.service"
GRASSD = Path(sys.executable).parent / "grassd"

needs_analyze = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None,
    reason="systemd-analyze is not installed (Debian: apt-get install systemd)")


def _unit_copy(tmp_path: Path, text: str | None = None) -> Path:
    """The unit with ExecStart's /usr/bin/grassd pointed at this checkout's grassd script
    (verify insists the binary exists); nothing else changes."""
    text = UNIT.read_text() if text is None else text
    out = tmp_path / "grassd.service"
    out.write_text(text.replace("/usr/bin/grassd", str(GRASSD)))
    return out


def _verify(path: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["systemd-analyze", "verify", str(path)],
                          capture_output=True, text=True, cwd=path.parent)


@needs_analyze
def test_verify_passes_with_empty_stderr(tmp_path):
    assert GRASSD.exists()
    r = _verify(_unit_copy(tmp_path))
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and r.stdout == ""


@needs_analyze
def test_verify_catches_a_typo(tmp_path):
    """The check above can fail: verify exits 0 on an unknown directive but warns on stderr."""
    text = UNIT.read_text().replace("ProtectSystem=strict", "ProtectSytem=strict")
    r = _verify(_unit_copy(tmp_path, text))
    assert "ProtectSytem" in r.stderr


@needs_analyze
def test_security_exposure_at_most_2(tmp_path):
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes",
                        str(_unit_copy(tmp_path))], capture_output=True, text=True,
                       cwd=tmp_path)
    m = re.search(r"Overall exposure level for grassd\.service: (\d+\.\d+)", r.stdout)
    assert m, r.stdout + r.stderr
    score = float(m.group(1))
    print(f"systemd-analyze security exposure: {score}")
    assert score <= 2.0


def test_unit_has_required_settings():
    text = UNIT.read_text()
    settings = {}
    for line in text.splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            k, _, v = line.partition("=")
            settings.setdefault(k.strip(), []).append(v.strip())
    assert settings["Type"] == ["notify"]
    assert settings["Restart"] == ["on-failure"]
    assert "WatchdogSec" in settings and settings["User"] == ["grassd"]
    assert settings["SupplementaryGroups"] == ["dialout"]
    assert settings["ProtectSystem"] == ["strict"]
    for d in ("StateDirectory", "ConfigurationDirectory", "RuntimeDirectory", "CacheDirectory"):
        assert settings[d] == ["grassd"], d
    assert "MemoryDenyWriteExecute" not in settings  # Taichi JITs with LLVM
    assert "PrivateDevices" not in settings          # would hide the ttys
    allowed = settings["DeviceAllow"]
    assert {a.split()[0] for a in allowed} == {"char-ttyUSB", "char-ttyACM", "char-ttyAMA"}
    assert settings["DevicePolicy"] == ["closed"]


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None or
                    shutil.which("systemd-tmpfiles") is None,
                    reason="systemd-sysusers/systemd-tmpfiles not installed")
def test_sysusers_and_tmpfiles_apply_to_a_scratch_root(tmp_path):
    (tmp_path / "etc").mkdir()
    subprocess.run(["systemd-sysusers", f"--root={tmp_path}",
                    str(ROOT / "systemd" / "grassd.sysusers.conf")], check=True,
                   capture_output=True)
    passwd = (tmp_path / "etc" / "passwd").read_text()
    group = (tmp_path / "etc" / "group").read_text()
    assert re.search(r"^grassd:x:\d+:\d+:.*:/var/lib/grassd:/usr/sbin/nologin$", passwd, re.M)
    assert re.search(r"^dialout:x:\d+:grassd$", group, re.M)
    subprocess.run(["systemd-tmpfiles", f"--root={tmp_path}", "--create",
                    str(ROOT / "systemd" / "grassd.tmpfiles.conf")], check=True,
                   capture_output=True)
    inbox = tmp_path / "var" / "lib" / "grassd" / "inbox"
    assert inbox.is_dir() and oct(inbox.stat().st_mode & 0o7777) == "0o2770"


def test_udev_rule_keeps_modemmanager_off():
    rules = (ROOT / "systemd" / "60-grassd-serial.rules").read_text()
    match_lines = [ln for ln in rules.splitlines() if ln.startswith("ATTRS{idVendor}")]
    assert len(match_lines) >= 3
    for ln in match_lines:
        assert 'ENV{ID_MM_DEVICE_IGNORE}="1"' in ln and 'GROUP="dialout"' in ln
        assert re.fullmatch(r'(\w+(\{\w+\})?(==|!=|=)"[^"]*"(, )?)+', ln), ln
    assert 'LABEL="grassd_serial_end"' in rules
