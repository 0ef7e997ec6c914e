"""The ports use the core through its functions and share code through firmware/generic/ (as
Klipper's src/generic/): no port includes another port's files or reads fw_controller's members,
and the Teensy sketch carries generic/'s critical sections byte for byte."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from firmware_tiers import missing_reason

FIRMWARE = Path(__file__).resolve().parents[2] / "firmware"
PORTS = sorted(p for p in (FIRMWARE / "ports").iterdir() if p.is_dir())


def port_sources(port: Path) -> list[Path]:
    return sorted(f for f in port.rglob("*") if f.suffix in {".c", ".h", ".ino"})


def controller_members() -> set[str]:
    """Member names of struct fw_controller (core/controller.h)."""
    text = (FIRMWARE / "core" / "controller.h").read_text()
    body = re.search(r"typedef struct fw_controller \{(.*?)\} fw_controller;", text, re.S).group(1)
    body = re.sub(r"/\*.*?\*/", "", body, flags=re.S)
    names = set()
    for decl in body.split(";"):
        for part in decl.split(","):
            m = re.search(r"(\w+)\s*(?:\[[^\]]*\]\s*)*$", part.strip())
            if m:
                names.add(m.group(1))
    return names


def test_no_port_includes_another_ports_files():
    for port in PORTS:
        for src in port_sources(port):
            for inc in re.findall(r'#include\s+"([^"]+)"', src.read_text()):
                assert not re.match(r"\.\./(?!\.\./)", inc), f"{src}: #include \"{inc}\""


def test_no_port_reads_the_controllers_members():
    members = controller_members()
    assert {"rx", "cfg", "wire", "motors"} <= members
    pattern = re.compile(r"\bctl\s*(?:\.|->)\s*(" + "|".join(sorted(members)) + r")\b")
    for port in PORTS:
        for src in port_sources(port):
            hits = pattern.findall(src.read_text())
            assert not hits, f"{src.relative_to(FIRMWARE)} reads fw_controller.{hits}"


@pytest.mark.skipif(missing_reason("posix") is not None, reason=str(missing_reason("posix")))
def test_teensy_sketch_carries_the_shared_critical_sections():
    from grassd.rigs.native_build import BUILD_DIR, build_firmware

    build_firmware("teensy41", "teensy41")
    sketch = BUILD_DIR / "teensy41" / "grassfw_teensy41"
    for src in sorted((FIRMWARE / "generic").glob("armcm_*.c")):
        assert (sketch / "src" / "generic" / src.name).read_bytes() == src.read_bytes()
    assert "fw_irq_save(void)\n{" not in (sketch / "grassfw_teensy41.ino").read_text()
