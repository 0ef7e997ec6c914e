"""The README is a short front door whose links and commands work, and ``docs/`` builds.

The documentation site (``mkdocs.yml``, ``docs/``) is built with ``mkdocs build --strict``, with
link and anchor validation turned into warnings by ``mkdocs.yml`` and so into errors by
``--strict``. The README (rendered on the forge and shipped as the package's long description)
must stay at most 12 KiB, show ``make demo`` and ``make test`` first, link only to files that
exist in the repository, and name only ``grassd`` commands that exist.
"""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MKDOCS_YML = ROOT / "mkdocs.yml"
#: the README's size limit: a newcomer reads it in five minutes
README_MAX_BYTES = 12 * 1024

#: ``grassd WORD [WORD]`` where a shell line runs it: at its start or after sudo, &&, ; or |
GRASSD_CALL = re.compile(
    r"(?:^[ \t]*|(?:sudo|&&|;|\|)[ \t]+)grassd ([a-z][a-z-]*)(?: ([a-z][a-z-]*))?", flags=re.M)

NO_MKDOCS = "mkdocs is not installed (it is in the test extra: pip install -e '.[test]')"
needs_mkdocs = pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason=NO_MKDOCS)


def _mkdocs_build(config: Path, site_dir: Path) -> subprocess.CompletedProcess:
    """``mkdocs build --strict`` of ``config`` into ``site_dir``, output captured."""
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(config),
         "--site-dir", str(site_dir)],
        capture_output=True, text=True, timeout=300)


def _readme() -> str:
    return README.read_text(encoding="utf-8")


def _without_fences(text: str) -> str:
    """``text`` without its fenced code blocks (links there are not links)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)


def _code(text: str) -> list[str]:
    """Every fenced code block and inline code span of ``text``."""
    fences = re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.M | re.S)
    spans = re.findall(r"`([^`\n]+)`", _without_fences(text))
    return fences + spans


def _command_table() -> list[tuple[str, str]]:
    """(command, description) of each row of the README's "Commands" table, command without
    the leading ``grassd``."""
    section = _readme().split("\n## Commands\n", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `grassd ([^`]+)` \| (.*) \|$", section, flags=re.M)
    assert rows, "the README's Commands section has no table of `grassd ...` rows"
    return rows


def _main() -> click.Group:
    from grassd.daemon.cli.main import main

    return main


@needs_mkdocs
def test_docs_site_builds_strict(tmp_path):
    """Every page builds, every link and anchor between pages resolves (firmware and protocol
    pages included, through docs/'s links to firmware/README.md and firmware_proto/PROTOCOL.md),
    and no page under docs/ is left out of the navigation."""
    res = _mkdocs_build(MKDOCS_YML, tmp_path / "site")
    assert res.returncode == 0, res.stderr[-4000:]
    assert (tmp_path / "site" / "index.html").is_file()
    assert (tmp_path / "site" / "firmware_proto" / "PROTOCOL" / "index.html").is_file()


@needs_mkdocs
def test_docs_build_fails_on_a_broken_link(tmp_path):
    """The strict build is not a formality: a link to a page that does not exist fails it."""
    shutil.copytree(ROOT / "docs", tmp_path / "docs", symlinks=False)
    shutil.copy(MKDOCS_YML, tmp_path / "mkdocs.yml")
    page = tmp_path / "docs" / "index.md"
    page.write_text(page.read_text(encoding="utf-8") + "\n[gone](no-such-page.md)\n",
                    encoding="utf-8")
    res = _mkdocs_build(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert res.returncode != 0
    assert "no-such-page.md" in res.stderr


def test_readme_is_at_most_12_kib():
    size = len(README.read_bytes())
    assert size <= README_MAX_BYTES, (
        f"README.md is {size} bytes, over {README_MAX_BYTES}: move detail into docs/")


def test_readme_shows_make_demo_and_make_test_first():
    """The first thing on the page is the code block with exactly the two commands."""
    text = _readme()
    first = re.search(r"^```[^\n]*\n(.*?)^```", text, flags=re.M | re.S)
    assert first is not None
    assert text[:first.start()].strip() == "# grassd"
    commands = [line.split("#", 1)[0].strip() for line in first.group(1).splitlines()]
    assert [c for c in commands if c] == ["make demo", "make test"]


def test_readme_relative_links_resolve_inside_the_repository():
    """Every relative link (``[text](path)``, anchors stripped) names an existing file or
    folder of the repository; none leaves it (``../shared/...`` is not in a clone)."""
    links = re.findall(r"\]\(([^)\s]+)\)", _without_fences(_readme()))
    relative = [link for link in links if not re.match(r"[a-z][a-z0-9+.-]*:|#", link)]
    assert relative, "the README links to no page of docs/"
    for link in relative:
        target = (ROOT / link.split("#", 1)[0]).resolve()
        assert target.is_relative_to(ROOT), f"{link} points outside the repository"
        assert target.exists(), f"README link {link} does not resolve"


def test_command_table_names_every_grassd_command_and_only_those():
    """The table lists each top-level command once, and each one it names exists."""
    named = [cmd.split()[0] for cmd, _ in _command_table()]
    assert len(named) == len(set(named)), named
    assert sorted(named) == sorted(_main().commands), (
        "the README's Commands table and `grassd --help` differ")


def test_command_table_rows_and_their_subcommands_run_with_help():
    """``grassd CMD --help`` runs for every row, and for a command group every bare word in
    backticks in its description (``list``, ``retry``) is one of its sub-commands."""
    main = _main()
    runner = CliRunner()
    for cmd, description in _command_table():
        words = cmd.split()
        res = runner.invoke(main, [*words, "--help"], prog_name="grassd")
        assert res.exit_code == 0, (cmd, res.output)
        group = main.commands[words[0]]
        if isinstance(group, click.Group):
            for sub in re.findall(r"`([a-z][a-z-]*)`", description):
                assert sub in group.commands, f"grassd {words[0]} has no sub-command {sub}"
                res = runner.invoke(main, [words[0], sub, "--help"], prog_name="grassd")
                assert res.exit_code == 0, (words[0], sub, res.output)


def test_every_grassd_command_in_readme_code_exists():
    """Each ``grassd WORD`` run in the README's code (blocks and inline: at the start of a line
    or after ``sudo``, ``&&``, ``;`` or ``|``) is a command, and a group's next bare word is one
    of its sub-commands."""
    main = _main()
    seen = set()
    for code in _code(_readme()):
        for m in GRASSD_CALL.finditer(code):
            name, sub = m.groups()
            assert name in main.commands, f"README names `grassd {name}`, which does not exist"
            seen.add(name)
            cmd = main.commands[name]
            if sub and isinstance(cmd, click.Group):
                assert sub in cmd.commands, f"README names `grassd {name} {sub}`"
    assert {"run", "status", "check-config"} <= seen, seen
