"""systemd units checked with Debian's systemd tools (systemd 252 on Debian 12), and the
groups of grassd.sysusers.conf / grassd.tmpfiles.conf: the daemon's own group, the uploaders'
(inbox) and the readers' (control socket), each granting only its own thing."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "systemd" / "grassd.service"
SYSUSERS = ROOT / "systemd" / "grassd.sysusers.conf"
TMPFILES = ROOT / "systemd" / "grassd.tmpfiles.conf"
UPLOADERS, READERS = "grassd-upload", "grassd-status"
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
def test_security_exposure_at_most_1_5(tmp_path):
    r = subprocess.run(["systemd-analyze", "security", "--offline=yes",
                        str(_unit_copy(tmp_path))], capture_output=True, text=True,
                       cwd=tmp_path)
    m = re.search(r"Overall exposure level for grassd\.service: (\d+\.\d+)", r.stdout)
    assert m, r.stdout + r.stderr
    score = float(m.group(1))
    print(f"systemd-analyze security exposure: {score}")
    assert score <= 1.5
    # the network lockdown is what systemd sees, not only text in the file
    assert re.search(r"IPAddressDeny=\s+Service defines IP address allow list", r.stdout), \
        r.stdout


def _settings() -> dict[str, list[str]]:
    settings: dict[str, list[str]] = {}
    for line in UNIT.read_text().splitlines():
        if "=" in line and not line.lstrip().startswith("#"):
            k, _, v = line.partition("=")
            settings.setdefault(k.strip(), []).append(v.strip())
    return settings


def _bytes(size: str) -> int:
    m = re.fullmatch(r"(\d+)([KMGT]?)", size)
    assert m, size
    return int(m.group(1)) * 1024 ** " KMGT".index(m.group(2) or " ")


def test_unit_has_required_settings():
    settings = _settings()
    assert settings["Type"] == ["notify"]
    assert settings["Restart"] == ["on-failure"]
    assert "WatchdogSec" in settings and settings["User"] == ["grassd"]
    assert settings["SupplementaryGroups"] == [f"dialout {UPLOADERS} {READERS}"]
    assert settings["ProtectSystem"] == ["strict"]
    for d in ("StateDirectory", "ConfigurationDirectory", "RuntimeDirectory", "CacheDirectory"):
        assert settings[d] == ["grassd"], d
    assert "MemoryDenyWriteExecute" not in settings  # Taichi JITs with LLVM
    assert "PrivateDevices" not in settings          # would hide the ttys
    allowed = settings["DeviceAllow"]
    assert {a.split()[0] for a in allowed} == {"char-ttyUSB", "char-ttyACM", "char-ttyAMA"}
    assert settings["DevicePolicy"] == ["closed"]


def test_unit_bounds_memory_network_and_config_access():
    """Hostile input: memory bounded (sized from the soak's RSS, the comment says so), no network
    but the camera's and the sensor's private ranges, no listening INET socket, the config
    (camera password) unreadable to anyone but root and the daemon."""
    settings = _settings()
    text = UNIT.read_text()
    high, top = _bytes(settings["MemoryHigh"][0]), _bytes(settings["MemoryMax"][0])
    soak_rss = 444 * 2**20  # docs/operating/service.md, "A year of bundles"
    assert soak_rss * 1.5 < high < top <= 4 * soak_rss
    assert "bench_soak" in text and "443-444 MiB" in text
    assert settings["IPAddressDeny"] == ["any"]
    allowed = " ".join(settings["IPAddressAllow"]).split()
    assert {"localhost", "10.0.0.0/8", "172.16.0.0/12", "192.168.0.0/16"} <= set(allowed)
    assert "any" not in allowed and "0.0.0.0/0" not in allowed
    assert "narrow them" in text  # per site
    assert settings["SocketBindDeny"] == ["any"]
    assert settings["ConfigurationDirectoryMode"] == ["0750"]
    for d in ("StateDirectoryMode", "RuntimeDirectoryMode", "CacheDirectoryMode"):
        assert int(settings[d][0], 8) & 0o006 == 0, d  # others: at most pass through


def test_each_group_is_named_for_what_it_grants():
    """The uploaders' and readers' groups are defined, said which is which in every file, and
    the control socket is handed to the readers' group."""
    settings = _settings()
    assert f"GRASSD_CONTROL_GROUP={READERS}" in settings["Environment"]
    sysusers = SYSUSERS.read_text()
    for group in (UPLOADERS, READERS):
        assert re.search(rf"^g\s+{group}\s", sysusers, re.M), group
        assert re.search(rf"^m\s+grassd\s+{group}\s*$", sysusers, re.M), group
    for path in (UNIT, SYSUSERS, TMPFILES):
        text = path.read_text()
        assert re.search(rf"{UPLOADERS}.*UPLOADERS|UPLOADERS.*{UPLOADERS}", text), path
        assert re.search(rf"{READERS}.*READERS|READERS.*{READERS}", text, re.S), path
    from grassd.daemon.core.runtime.control import GROUP_ENV
    assert GROUP_ENV == "GRASSD_CONTROL_GROUP"


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None or
                    shutil.which("systemd-tmpfiles") is None,
                    reason="systemd-sysusers/systemd-tmpfiles not installed")
def test_sysusers_and_tmpfiles_apply_to_a_scratch_root(tmp_path):
    (tmp_path / "etc").mkdir()
    subprocess.run(["systemd-sysusers", f"--root={tmp_path}", str(SYSUSERS)], check=True,
                   capture_output=True)
    passwd = (tmp_path / "etc" / "passwd").read_text()
    group = (tmp_path / "etc" / "group").read_text()
    assert re.search(r"^grassd:x:\d+:\d+:.*:/var/lib/grassd:/usr/sbin/nologin$", passwd, re.M)
    gids = {}
    for g in ("dialout", UPLOADERS, READERS, "grassd"):
        m = re.search(rf"^{g}:x:(\d+):(.*)$", group, re.M)
        assert m, g
        gids[g] = int(m.group(1))
        members = m.group(2).split(",") if m.group(2) else []
        assert members == ([] if g == "grassd" else ["grassd"]), (g, members)
    assert len(set(gids.values())) == 4
    r = subprocess.run(["systemd-tmpfiles", f"--root={tmp_path}", "--create", str(TMPFILES)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    # under --root the file owners are the scratch root's ids: compare the group ids
    def mode_gid(*parts: str) -> tuple[str, int]:
        st = tmp_path.joinpath(*parts).stat()
        return oct(st.st_mode & 0o7777), st.st_gid
    assert mode_gid("var", "lib", "grassd", "inbox") == ("0o2770", gids[UPLOADERS])
    assert mode_gid("var", "lib", "grassd") == ("0o751", gids["grassd"])
    assert mode_gid("etc", "grassd") == ("0o750", gids["grassd"])  # camera password


def test_udev_rule_keeps_modemmanager_off():
    rules = (ROOT / "systemd" / "60-grassd-serial.rules").read_text()
    match_lines = [ln for ln in rules.splitlines() if ln.startswith("ATTRS{idVendor}")]
    assert len(match_lines) >= 3
    for ln in match_lines:
        assert 'ENV{ID_MM_DEVICE_IGNORE}="1"' in ln and 'GROUP="dialout"' in ln
        assert re.fullmatch(r'(\w+(\{\w+\})?(==|!=|=)"[^"]*"(, )?)+', ln), ln
    assert 'LABEL="grassd_serial_end"' in rules
