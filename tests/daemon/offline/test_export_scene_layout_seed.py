"""``grassd simulate export-scene --layout-seed``: the exported meshes are the tuft layout the
seed draws (another seed, other blades; the same seed, the same bytes), and the deprecated
``--seed``, which seeds camera paths an exported scene does not hold, says so."""

from __future__ import annotations

from pathlib import Path

from click.testing import CliRunner

from grassd.daemon.cli.main import main


def _export(out: Path, hdri: Path, *extra: str):
    return CliRunner().invoke(main, ["simulate", "export-scene", "--hdri", str(hdri), "--lux",
                                     "5000", "--length", "12", "--view", "170,2,0", "--out",
                                     str(out), *extra])


def _plys(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.glob("*.ply"))}


def test_layout_seed_chooses_the_exported_blades(tmp_path, shared_hdri):
    hdri = shared_hdri("courtyard")
    runs = {}
    for name, seed in (("a", "3"), ("b", "3"), ("c", "4")):
        res = _export(tmp_path / name, hdri, "--layout-seed", seed)
        assert res.exit_code == 0, res.output
        runs[name] = _plys(tmp_path / name)
    assert {"yellow_grass.ply", "green_grass.ply"} <= set(runs["a"])
    assert runs["a"] == runs["b"]  # the same seed: byte-identical meshes
    for name in ("yellow_grass.ply", "green_grass.ply"):  # another seed: other blades
        assert runs["a"][name] != runs["c"][name], name
    default = _export(tmp_path / "d", hdri)
    assert default.exit_code == 0, default.output
    assert _plys(tmp_path / "d") != runs["a"]


def test_the_old_seed_warns_and_changes_nothing(tmp_path, shared_hdri):
    hdri = shared_hdri("courtyard")
    plain = _export(tmp_path / "plain", hdri)
    old = _export(tmp_path / "old", hdri, "--seed", "7")
    assert plain.exit_code == 0 and old.exit_code == 0, old.output
    assert "deprecated" in old.output and "--layout-seed" in old.output
    assert "deprecated" not in plain.output
    assert _plys(tmp_path / "old") == _plys(tmp_path / "plain")
