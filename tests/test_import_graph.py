"""The package layout holds on the real import graph:

* ``grassd run`` never imports ``grassd.daemon.offline`` (validation, experiments, sweeps,
  reports): a real ``grassd run --simulate-hardware`` in a subprocess calibrates one bundle and
  pushes its table, then lists the modules it loaded;
* nor does any module the daemon runs (``runtime``, ``measure``, ``calibration``, ``hardware``,
  ``monitoring``, ``store``, ``config``): no import statement in them names an offline module,
  lazy or not, so a scheduled measurement or a path the first test does not take cannot either;
* ``grassd.calib``, ``grassd.sim`` and ``grassd.firmware_proto`` never import ``grassd.daemon``
  (no import statement anywhere in them names it, lazy or not);
* no runtime path imports a rig: no module of ``grassd.calib``, ``grassd.sim``,
  ``grassd.firmware_proto`` or ``grassd.daemon`` imports a module of ``grassd.rigs`` (test rigs
  and simulated hardware), lazy or not, but the entry points that serve simulated hardware
  (``grassd/rigs/__init__.py`` states the rule); importing the command line loads none;
* no import cycles between modules at module level (imports inside functions and under
  ``if TYPE_CHECKING:`` do not run at import time and are left out);
* no import cycles between the daemon's subpackages, counting every import,
  lazy or not;
* every import of a grassd module, lazy or not, in the packages, tests and benchmarks names a
  module that exists.

The static checks read every module of the five packages with :mod:`ast`, so a new module is
covered as soon as it exists.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

from daemon_harness import DISPLAY_2X2, drop_midsummer

ROOT = Path(__file__).resolve().parents[1]
#: source folder -> package (pyproject's package-dir)
PACKAGES = {"grassd": "grassd", "calib": "grassd.calib", "sim": "grassd.sim",
            "firmware_proto": "grassd.firmware_proto", "rigs": "grassd.rigs",
            "daemon": "grassd.daemon"}


def _modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the distribution."""
    out = {}
    for folder, package in PACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join([package, *parts])] = path
    return out


MODULES = _modules()


def _imports(path: Path) -> list[tuple[str, bool]]:
    """(imported grassd module, runs at import time) for every import statement in ``path``.
    ``from a import b`` counts as importing ``a`` and, when ``a.b`` is a module, ``a.b``."""
    found: list[tuple[str, bool]] = []

    def visit(node: ast.AST, at_import: bool) -> None:
        for child in ast.iter_child_nodes(node):
            now = at_import and not isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef
                                                 | ast.Lambda)
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                now = False
            if isinstance(child, ast.Import):
                found.extend((a.name, now) for a in child.names)
            elif isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
                found.append((child.module, now))
                found.extend((f"{child.module}.{a.name}", now) for a in child.names
                             if f"{child.module}.{a.name}" in MODULES)
            visit(child, now)

    visit(ast.parse(path.read_text(), str(path)), True)
    return [(name, now) for name, now in found if name.split(".")[0] == "grassd"]


def test_the_graph_sees_every_package():
    """Precondition of the other checks: the walk finds the modules and their imports."""
    assert {"grassd.daemon.core.runtime.service", "grassd.daemon.cli.main", "grassd.sim.renderer",
            "grassd.calib.ogcd", "grassd.firmware_proto.client"} <= set(MODULES)
    run = _imports(MODULES["grassd.daemon.cli.run"])
    assert ("grassd.daemon.core.config.settings", True) in run
    assert ("grassd.daemon.core.runtime.service", False) in run
    assert ("grassd.sim.renderer", False) in _imports(
        MODULES["grassd.daemon.core.calibration.calibrate"])  # lazy: not at import time


def test_every_grassd_import_names_an_existing_module():
    """Lazy imports too (a moved module leaves no stale path behind), in the packages, the
    tests and the benchmarks."""
    files = [*MODULES.values(), *sorted((ROOT / "tests").rglob("*.py")),
             *sorted((ROOT / "bench").glob("*.py"))]
    missing = sorted({f"{path.relative_to(ROOT)}: {name}" for path in files
                      for name, _ in _imports(path) if name not in MODULES})
    assert not missing, missing


def test_calib_sim_and_firmware_proto_never_import_the_daemon():
    bad = [f"{name} imports {imported}"
           for name, path in MODULES.items()
           if name.startswith(("grassd.calib", "grassd.sim", "grassd.firmware_proto"))
           for imported, _ in _imports(path) if imported.startswith("grassd.daemon")]
    assert not bad, bad


#: The command-line modules that serve simulated hardware: the only modules outside grassd.rigs
#: that import its modules, each only inside the functions of those commands.
SIMULATED_HARDWARE_ENTRY_POINTS = (
    "grassd.daemon.cli.run",  # grassd run --simulate-hardware, grassd demo
    "grassd.daemon.cli.controllers",  # grassd controllers sim
    "grassd.daemon.capture.cli",  # grassd camera sim
    "grassd.daemon.measure.cli",  # grassd measure --simulate-hardware
)


def _is_rig(imported: str) -> bool:
    return imported == "grassd.rigs" or imported.startswith("grassd.rigs.")


def test_no_rig_imported_by_a_runtime_path():
    """Test rigs and simulated hardware (``grassd.rigs``) are imported by no module of calib,
    sim, firmware_proto or daemon, lazily or not, but inside the functions of the commands that
    serve simulated hardware; the daemon may import the package itself (``from grassd.rigs
    import FIRMWARE_BACKENDS``: the command line's choices), whose ``__init__`` imports
    nothing."""
    assert {"grassd.rigs", "grassd.rigs.simulator", "grassd.rigs.golden",
            "grassd.rigs.mitsuba_scene", "grassd.rigs.simulated_site"} <= set(MODULES)
    assert set(SIMULATED_HARDWARE_ENTRY_POINTS) <= set(MODULES)
    init = ast.parse(MODULES["grassd.rigs"].read_text())
    assert not [node for node in ast.walk(init)
                if isinstance(node, ast.Import | ast.ImportFrom)
                and getattr(node, "module", None) != "__future__"], "grassd.rigs imports"
    bad = []
    for name, path in MODULES.items():
        if name == "grassd" or _is_rig(name):
            continue
        for imported, now in _imports(path):
            if not _is_rig(imported):
                continue
            if imported == "grassd.rigs" and name.startswith("grassd.daemon"):
                continue  # the command line's choices only
            if name in SIMULATED_HARDWARE_ENTRY_POINTS and not now:
                continue
            bad.append(f"{name} imports {imported}" + (" at module level" if now else ""))
    assert not bad, bad


def test_the_command_line_loads_no_rig():
    """What the static rule promises, on the real import: loading ``grassd`` with every command
    (as ``grassd run`` on a site does) loads the rigs' name list and no rig module."""
    code = ("import sys; from grassd.daemon.cli.main import main; "
            "[main.commands[name] for name in list(main.commands)]; "  # each loads on first use
            "print(sorted(m for m in sys.modules if m.startswith('grassd.rigs')))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split("\n")[-2] == "['grassd.rigs']", proc.stdout


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in graph[v]:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles_at_module_level():
    graph = {name: {m for m, now in _imports(path) if now and m in MODULES and m != name}
             for name, path in MODULES.items()}
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert not _cycles(graph), _cycles(graph)


#: The daemon's folders by role: the core (all that ``grassd run`` needs to turn a bundle into
#: tables on controllers), the features (each joins the service from its own folder), the
#: tools (never imported by the service) and the command line that puts them together.
CORE = "grassd.daemon.core"
FEATURES = ("grassd.daemon.capture", "grassd.daemon.measure", "grassd.daemon.compute",
            "grassd.daemon.content")
TOOLS = ("grassd.daemon.studio", "grassd.daemon.offline")
#: What features share: the OSC camera (capture and measure photograph with it). It imports
#: the core only; features and tools may import it.
SHARED = ("grassd.daemon.camera",)
COMMAND_LINE = "grassd.daemon.cli"
#: The core's imports of a feature (or of what features share) that remain, each named (core
#: module, feature module): the configuration still reads these sections by name. The list
#: may only shrink: a new edge fails, and so does one that is gone but still listed.
CORE_IMPORTS_OF_FEATURES = {
    ("grassd.daemon.core.config.settings", "grassd.daemon.compute.config"),
    ("grassd.daemon.core.config.settings", "grassd.daemon.content.config"),
    ("grassd.daemon.core.config.settings", "grassd.daemon.measure.config"),
    ("grassd.daemon.core.config.settings", "grassd.daemon.camera.config"),
}


def _area(module: str) -> str | None:
    """The folder of the daemon a module belongs to: ``grassd.daemon.core`` (and its own
    subpackages, ``grassd.daemon.core.<sub>``), a feature, a tool or the command line (None
    for anything outside the daemon)."""
    parts = module.split(".")
    if parts[:2] != ["grassd", "daemon"] or len(parts) < 3:
        return None
    if parts[2] == "core" and len(parts) > 3 and (ROOT / "daemon" / "core" / parts[3]).is_dir():
        return ".".join(parts[:4])
    return ".".join(parts[:3])


def _edges() -> list[tuple[str, str]]:
    """(importing module, imported module) for every import of a daemon module, lazy or not."""
    return [(name, imported) for name, path in MODULES.items() if _area(name)
            for imported, _ in _imports(path) if _area(imported) and imported in MODULES]


def _in(module: str, *areas: str) -> bool:
    return any(module == a or module.startswith(a + ".") for a in areas)


def test_the_daemon_is_a_core_with_features_and_tools_around_it():
    """Every daemon module is in the core, a feature, a tool or the command line; features and
    tools exist (the layout docs/architecture.md draws)."""
    assert {_area(m) for m in MODULES if m.startswith("grassd.daemon.")} - {None} <= {
        *(a for a in {_area(m) for m in MODULES} if a and a.startswith(CORE)), CORE,
        *FEATURES, *TOOLS, *SHARED, COMMAND_LINE}
    for area in (*FEATURES, *TOOLS, *SHARED):
        assert area in MODULES, area


def test_the_core_imports_no_feature_tool_or_command_line():
    """The core never imports a tool or the command line, and a feature only where
    :data:`CORE_IMPORTS_OF_FEATURES` still names the edge."""
    edges = _edges()
    tools = sorted(f"{a} imports {b}" for a, b in edges
                   if _in(a, CORE) and _in(b, *TOOLS, COMMAND_LINE))
    assert not tools, tools
    features = {(a, b) for a, b in edges if _in(a, CORE) and _in(b, *FEATURES, *SHARED)}
    assert not features - CORE_IMPORTS_OF_FEATURES, sorted(features - CORE_IMPORTS_OF_FEATURES)
    assert not CORE_IMPORTS_OF_FEATURES - features, sorted(CORE_IMPORTS_OF_FEATURES - features)


def test_features_import_neither_each_other_nor_tools():
    bad = sorted(f"{a} imports {b}" for a, b in _edges()
                 for feature in FEATURES if _in(a, feature)
                 and (_in(b, *TOOLS, COMMAND_LINE) or (_in(b, *FEATURES) and not _in(b, feature))))
    assert not bad, bad


def test_what_features_share_imports_only_the_core():
    bad = sorted(f"{a} imports {b}" for a, b in _edges()
                 if _in(a, *SHARED) and _in(b, *FEATURES, *TOOLS, COMMAND_LINE))
    assert not bad, bad
    users = {_area(a) for a, b in _edges() if _in(b, *SHARED) and not _in(a, *SHARED)}
    assert {"grassd.daemon.capture", "grassd.daemon.measure"} <= users, users


def test_tools_import_no_command_line():
    bad = sorted(f"{a} imports {b}" for a, b in _edges()
                 if _in(a, *TOOLS) and _in(b, COMMAND_LINE))
    assert not bad, bad


def test_tests_never_import_the_benchmarks():
    """Fixtures live in tests/ (or in grassd.rigs); bench/ is for ``make bench`` only."""
    bad = []
    for path in sorted((ROOT / "tests").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{path.relative_to(ROOT)}: {n}" for n in names
                    if n.split(".")[0] == "bench" or (n.split(".")[0] in _BENCH_MODULES)]
    assert not bad, bad


#: the benchmarks' own modules (bench/*.py), which tests reach as top-level names when bench/ is
#: on sys.path
_BENCH_MODULES = {p.stem for p in (ROOT / "bench").glob("*.py")} - {"__init__", "__main__"}


def test_no_import_cycles_between_daemon_areas():
    """The core's subpackages, the features, the tools and the command line depend on each
    other one way: no two import each other, directly or round a loop. Every import statement
    counts, lazy or under ``if TYPE_CHECKING:`` too (either way one names the other's modules,
    so neither can change or move alone), but the core's imports of features that
    :data:`CORE_IMPORTS_OF_FEATURES` still names."""
    graph: dict[str, set[str]] = {}
    why: dict[tuple[str, str], list[str]] = {}
    for name, imported in _edges():
        if (name, imported) in CORE_IMPORTS_OF_FEATURES:
            continue
        a, b = _area(name), _area(imported)
        graph.setdefault(a, set())
        graph.setdefault(b, set())
        if a != b:
            graph[a].add(b)
            why.setdefault((a, b), []).append(f"{name} imports {imported}")
    assert {"grassd.daemon.core.runtime", "grassd.daemon.core.monitoring",
            "grassd.daemon.measure"} <= set(graph)
    bad = [{"cycle": cycle, "imports": sorted(i for a in cycle for b in cycle
                                              for i in why.get((a, b), []))}
           for cycle in _cycles(graph)]
    assert not bad, bad


#: run in a subprocess: ``grassd run --simulate-hardware`` until its first run is ok, then
#: SIGTERM; prints the grassd modules the process loaded
_RUN = """
import json, os, signal, sys, threading, time
from grassd.daemon.cli.main import main
from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.runtime.control import request

config = sys.argv[1]
sock = load_config(config).control_socket
ok = []

def watch():
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not ok:
        try:
            st = request(sock, {"cmd": "status"}, timeout_s=5)["status"]
            if st["run_counts"]["ok"] and st["health"] == "ok":
                ok.append(st)
        except Exception:
            pass
        time.sleep(0.2)
    os.kill(os.getpid(), signal.SIGTERM)

threading.Thread(target=watch, daemon=True).start()
try:
    main(["run", "--config", config, "--simulate-hardware", "--tick", "0.2",
          "--log-level", "warning"], standalone_mode=False)
except SystemExit:
    pass
print(json.dumps({"ok": bool(ok), "modules": sorted(m for m in sys.modules
                                                    if m.startswith("grassd"))}))
"""


def test_no_module_the_daemon_runs_names_a_tool():
    """Every import statement, lazy or not, of the core and the features names no module of a
    tool (the studio, the offline work)."""
    bad = [f"{name} imports {imported}" for name, path in MODULES.items()
           if _in(name, CORE, *FEATURES)
           for imported, _ in _imports(path) if _in(imported, *TOOLS)]
    assert any(n.startswith("grassd.daemon.measure.") for n in MODULES)
    assert not bad, bad


def test_grassd_run_never_imports_offline(tmp_path):
    """A real ``grassd run`` calibrates a bundle and pushes the table to (simulated) controllers
    without loading any module of grassd.daemon.offline."""
    from grassd.daemon.core.config.settings import parse_config

    config = tmp_path / "grassd.toml"
    config.write_text(DISPLAY_2X2)
    inbox = parse_config(DISPLAY_2X2, base_dir=tmp_path).light.inbox
    inbox.mkdir(parents=True)
    drop_midsummer(inbox, "b1")
    proc = subprocess.run([sys.executable, "-c", _RUN, str(config)], capture_output=True,
                          text=True, timeout=400, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["ok"], f"no successful run; stderr: {proc.stderr[-3000:]}"
    loaded = out["modules"]
    assert "grassd.daemon.core.runtime.service" in loaded and "grassd.daemon.cli.main" in loaded
    assert "grassd.daemon.core.calibration.calibrate" in loaded
    offline = [m for m in loaded if m.startswith("grassd.daemon.offline")]
    assert not offline, offline


#: Libraries that take seconds or tens of MiB to import: the light commands load none
#: (``grassd --help`` and ``grassd status`` in 0.3 s, ``grassd check-config`` in 0.5 s).
#: numpy too: none of the three needs it.
HEAVY = ("taichi", "colour", "colour_hdri", "matplotlib", "pandas", "scipy", "numpy", "dask",
         "distributed", "aiohttp", "prometheus_client", "PIL", "OpenEXR", "rawpy", "pvlib")
#: Modules that `grassd status` does without, each tens of ms of its 0.3 s: the protocol's
#: message classes (the configuration needs only the address range, from the frame header),
#: importlib.resources (the embedded default configuration is read beside its module) with
#: the tempfile, zipfile and shutil it brings
STATUS_NEEDS_NOT = ("grassd.firmware_proto.messages", "importlib.resources", "tempfile",
                    "zipfile", "shutil")

#: run in a subprocess: ``grassd ARGS...`` as the console script runs it, then the heavy
#: libraries loaded (one JSON line)
_LIGHT = """
import json, sys
from grassd.daemon.cli.main import main
try:
    main(sys.argv[2:], prog_name="grassd", standalone_mode=False)
except SystemExit as exc:
    assert not exc.code, exc.code
heavy = json.loads(sys.argv[1])
print(json.dumps(sorted({m.split(".")[0] for m in sys.modules} & set(heavy))
                 + sorted(set(sys.modules) & set(heavy))))
"""


def _heavy_loaded(tmp_path: Path, *args: str, also: tuple[str, ...] = ()
                  ) -> tuple[list[str], str]:
    """(the :data:`HEAVY` libraries and the modules ``also`` that ``grassd ARGS`` loaded,
    what it printed)."""
    proc = subprocess.run([sys.executable, "-c", _LIGHT, json.dumps([*HEAVY, *also]), *args],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stdout


def test_grassd_help_loads_no_heavy_library(tmp_path):
    """``grassd --help`` lists every command without importing one."""
    loaded, out = _heavy_loaded(tmp_path, "--help")
    assert "check-config" in out and "Commands:" in out
    assert not loaded, loaded


def test_grassd_check_config_loads_no_heavy_library(tmp_path):
    """``grassd check-config`` on the embedded default configuration, written to a file."""
    from grassd.daemon.core.config.settings import default_config_text

    config = tmp_path / "grassd.toml"
    config.write_text(default_config_text())
    loaded, out = _heavy_loaded(tmp_path, "check-config", "--config", str(config))
    assert f"{config}: OK" in out
    assert not loaded, loaded


def test_grassd_status_without_a_daemon_loads_no_heavy_library(tmp_path):
    """``grassd status`` with no daemon running reads the state database: a finished run with
    its display-wide table (the default), a push. (A run with a table of its own per controller
    or pixel reads those as numpy arrays.)"""
    from grassd.daemon.core.config.settings import default_config_text
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.layout import StateLayout

    config = tmp_path / "grassd.toml"
    config.write_text(default_config_text())
    state = tmp_path / "state"
    db = StateLayout(state).db
    db.parent.mkdir(parents=True, exist_ok=True)
    with History(db) as h:
        run = h.start_run("manual", lux=1000.0, lux_source="manifest")
        names = ["/dev/serial/by-id/usb-grassd_controller_0-if00#1",
                 "/dev/serial/by-id/usb-grassd_controller_1-if00#2"]
        h.finish_run(run, "ok", table_id=1, table_crc=7, lengths_um=[1000] * 256,
                     metrics={"r2_closed_loop": 0.99, "max_dev_de00": 0.4})
        h.record_push(run, names[0], True, table_id=1, table_crc=7)
    loaded, out = _heavy_loaded(tmp_path, "status", "--config", str(config), "--state-dir",
                                str(state), also=STATUS_NEEDS_NOT)
    assert "daemon: not running" in out and f"#{run} " in out
    assert "current table: 1 (crc 0x00000007)" in out
    assert not loaded, loaded


def test_the_daemon_loads_no_colour_science_or_taichi_before_its_first_run():
    """What ``grassd run`` imports before it calibrates (the service and the command) holds no
    colour-science (with its plotting: matplotlib, pandas), Taichi or Dask: an idle daemon
    whose simulations run on a cluster stays small (150 MiB; numpy and scipy, for
    the inbox's light checks, it has). Taichi loads when the daemon initialises its renderer,
    colour-science at the first colour difference."""
    code = ("import json, sys, grassd.daemon.core.runtime.service, grassd.daemon.cli.run; "
            f"print(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}} & {set(HEAVY)!r})))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    loaded = set(json.loads(proc.stdout.strip().splitlines()[-1]))
    assert "numpy" in loaded  # the check sees imports
    assert not loaded & {"taichi", "colour", "colour_hdri", "matplotlib", "pandas", "dask",
                         "distributed", "aiohttp"}, loaded
