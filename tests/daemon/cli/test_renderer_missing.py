"""Where Taichi cannot be imported (as on Linux aarch64, which it has no wheels for), every
command that renders says so in one line, with the two ways out, and exits 2; the daemon's
commands with a Dask scheduler go on without it. Each command runs as a real `grassd` process
in a Python where ``import taichi`` fails."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from grassd.daemon.core.config.settings import default_config_text
from grassd.sim.hdri import default_site_hdri

#: `grassd` in a Python where ``import taichi`` fails, as where Taichi has no wheels
NO_TAICHI = ("import sys; sys.modules['taichi'] = None; "
             "from grassd.daemon.cli.main import main; main()")
SITE = str(default_site_hdri())


def grassd_without_taichi(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", NO_TAICHI, *args], capture_output=True,
                          text=True, timeout=120, cwd=cwd)


@pytest.mark.parametrize("args", [
    ["simulate", "--hdri", SITE, "--lux", "5000", "--view", "170,2,0"],
    ["sweep", "--hdri", SITE, "--view", "170,2,0", "--out", "sweep"],
    ["experiment", "virtual-capture", "--hdri", SITE, "--lux", "5000", "capture"],
    ["studio", "--port", "0", "--hdri", SITE, "--state-dir", "state"],
    ["calibrate", "--now", "--simulate-hardware", "--state-dir", "state"],
    ["run", "--simulate-hardware", "--state-dir", "state"],
], ids=lambda a: " ".join(a[:2]))
def test_a_command_that_renders_says_taichi_is_missing_in_one_line(args, tmp_path):
    res = grassd_without_taichi(args, tmp_path)
    assert res.returncode == 2, res.stderr
    errors = [ln for ln in res.stderr.splitlines() if ln.startswith("grassd: error: ")]
    assert len(errors) == 1, res.stderr
    assert errors[0].startswith("grassd: error: the renderer needs Taichi, which is not "
                                "installed here (")
    assert "pip install 'grassd[sim]'" in errors[0] and "[compute] scheduler" in errors[0]
    assert "Traceback" not in res.stderr


def test_calibrate_with_a_scheduler_needs_no_taichi(tmp_path):
    """--scheduler takes the one-shot run to the cluster: here, a port nobody listens on,
    so the run fails for the cluster, not for the renderer."""
    from dask_cluster import free_port

    config = tmp_path / "grassd.toml"
    config.write_text(default_config_text()
                      + "\n[compute]\nallow_insecure = true\nconnect_timeout_s = 1.0\n")
    address = f"tcp://127.0.0.1:{free_port()}"
    res = grassd_without_taichi(["calibrate", "--now", "--simulate-hardware", "--config",
                                 str(config), "--state-dir", "state", "--scheduler", address],
                                tmp_path)
    assert res.returncode == 2, res.stderr
    assert f"grassd: error: one-shot run failed: cannot reach the Dask scheduler at {address}" \
        in res.stderr
    assert "needs Taichi" not in res.stderr and "Traceback" not in res.stderr
    bad = grassd_without_taichi(["calibrate", "--now", "--scheduler", "calib:8786"], tmp_path)
    assert bad.returncode == 2 and "--scheduler" in bad.stderr and "tls://host:8786" in bad.stderr
    # a scheduler without TLS needs allow_insecure in [compute], as one written there
    (tmp_path / "strict.toml").write_text(default_config_text())
    strict = grassd_without_taichi(["calibrate", "--now", "--config", str(tmp_path / "strict.toml"),
                                    "--state-dir", "state", "--scheduler", address], tmp_path)
    assert strict.returncode == 2 and "has no TLS" in strict.stderr, strict.stderr
    assert "allow_insecure = true" in strict.stderr and "Traceback" not in strict.stderr
