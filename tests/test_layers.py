"""The layer rules of docs/architecture.md, checked on the source: every import that runs counts,
also the function-local (lazy) ones; a name imported under `if TYPE_CHECKING` for annotations
loads nothing and is not counted.

- No import cycle between modules, nor between units (a subpackage such as `prsm_ros.bag`, or a
  top-level module such as `prsm_sim.params`).
- No upward import: a unit imports only units of a lower layer (`LAYERS`) or itself.
- `prsm_sim` never imports `prsm_ros`, rclpy, a ROS message package, mcap or rerun.
- No private name (leading underscore) imported from another module, nor from a third party's
  private package (`pkg._vendor`); a package's private submodule (`pkg._impl`) may be imported
  by the modules of that package.

Oracle: the import statements themselves (Python's `ast`), read without importing anything.
"""

from __future__ import annotations

import ast
import functools
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("prsm_sim", "prsm_ros")

# Lowest layer first. A unit is a subpackage (`prsm_ros.bag`) or a top-level module
# (`prsm_sim.params`); a unit may import units of its own or a lower layer only.
# The package roots (`prsm_sim`, `prsm_ros`: their __init__) sit above their units.
LAYERS: tuple[tuple[str, ...], ...] = (
    # prsm_sim: the pure core
    ("prsm_sim.errors", "prsm_sim.checks"),
    ("prsm_sim.physics", "prsm_sim.plain"),  # closed-form physics on parameter groups; records as plain data
    ("prsm_sim.params",),  # parameter groups, validated where built (with the physics they derive ratings from)
    ("prsm_sim.presets", "prsm_sim.life", "prsm_sim.stepping"),  # named sets; life; the records and model contract
    ("prsm_sim.outputs",),  # the records' former home, kept as an alias
    ("prsm_sim.models",),  # the models, their compiled kernels and the registry above them
    ("prsm_sim.actuator", "prsm_sim.end_steps"),  # drive, motor, sensors, brake, faults around a model; a bare model's ends
    ("prsm_sim.simulator", "prsm_sim.control"),
    ("prsm_sim.command_gate", "prsm_sim.scenarios"),  # the gate; standard runs
    ("prsm_sim.session", "prsm_sim.datasheet"),  # the runtime session; a model's catalogue figures, a plant from a sheet
    ("prsm_sim.envelope", "prsm_sim.calibration", "prsm_sim.identify"),  # edge cases; friction fitted to a sheet; fits to recordings
    ("prsm_sim",),
    # prsm_ros: all I/O
    ("prsm_ros.interface", "prsm_ros.cdr_read", "prsm_ros.ros_env", "prsm_ros.json_out",
     "prsm_ros.param_files", "prsm_ros.limits", "prsm_ros.description",
     "prsm_ros.interrupts"),  # the ROS interface as plain data, CDR reading, JSON, parameter files, input limits; the xacro macro (data); a handled Ctrl-C's exit
    ("prsm_ros.cdr_write",),  # per-step messages as CDR bytes (rclpy)
    ("prsm_ros.messages",),  # the interface bound to rclpy
    ("prsm_ros.mcap", "prsm_ros.ray_runner"),  # MCAP schema, codec, recorder, offline runs; joining or starting Ray
    ("prsm_ros.sweep",),  # studies on Ray
    ("prsm_ros.bag",),  # reading, exporting, reporting, comparing bags
    ("prsm_ros.viz", "prsm_ros.live"),  # Rerun views, live and from bags; the live Foxglove server
    ("prsm_ros.node",),  # the rclpy node
    ("prsm_ros.fmu", "prsm_ros.fit"),  # the actuator as an FMU; identifying it from recordings
    ("prsm_ros.cli",),  # the command-line tools
    ("prsm_ros.bench",),  # benchmarks
    ("prsm_ros",),
)
RANK = {unit: i for i, layer in enumerate(LAYERS) for unit in layer}
FORBIDDEN_IN_CORE = ("prsm_ros", "rclpy", "mcap", "mcap_ros2", "rerun", "rosbag2_py", "std_msgs", "sensor_msgs",
                     "geometry_msgs", "builtin_interfaces", "diagnostic_msgs", "rosgraph_msgs", "rcl_interfaces")


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


MODULES = _modules()


@functools.cache
def _tree(mod: str) -> ast.Module:
    """The parsed source of a project module, parsed once for every check here."""
    return ast.parse(MODULES[mod].read_text(encoding="utf-8"))


def _is_package(mod: str) -> bool:
    return MODULES[mod].name == "__init__.py"


def _type_checking_only(tree: ast.AST) -> set[int]:
    """ids of the import nodes under `if TYPE_CHECKING:` (names for annotations: nothing is loaded)."""
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and isinstance(node.test, (ast.Name, ast.Attribute)) \
                and (getattr(node.test, "id", None) or getattr(node.test, "attr", None)) == "TYPE_CHECKING":
            inside |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return inside


def _imports(mod: str, source: str | None = None) -> list[tuple[str, str | None, int]]:
    """(module imported, name imported from it or None, line) for every import statement in `mod`
    that runs: at the top, in a function, under a condition; not those under `if TYPE_CHECKING`."""
    return list(_module_imports(mod) if source is None else _imports_in(mod, ast.parse(source)))


@functools.cache
def _module_imports(mod: str) -> tuple[tuple[str, str | None, int], ...]:
    return _imports_in(mod, _tree(mod))


def _imports_in(mod: str, tree: ast.Module) -> tuple[tuple[str, str | None, int], ...]:
    out: list[tuple[str, str | None, int]] = []
    annotation_only = _type_checking_only(tree)
    for node in ast.walk(tree):
        if id(node) in annotation_only:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, None, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolved against the importing module's package
                pkg = mod.split(".") if _is_package(mod) else mod.split(".")[:-1]
                pkg = pkg[:len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([base] if base else []))
            out += [(base, a.name, node.lineno) for a in node.names]
    return tuple(out)


def _own_target(name: str, attr: str | None) -> str | None:
    """The project module an import reaches (a submodule when `from pkg import submodule`), or None."""
    if attr is not None and f"{name}.{attr}" in MODULES:
        return f"{name}.{attr}"
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _unit(mod: str) -> str:
    """The subpackage a module belongs to, or the module itself when it sits at a package's top."""
    parts = mod.split(".")
    if len(parts) == 1:
        return mod
    if len(parts) == 2 and not _is_package(mod):
        return mod
    return ".".join(parts[:2])


def _edges() -> dict[str, set[str]]:
    edges: dict[str, set[str]] = defaultdict(set)
    for mod in MODULES:
        for name, attr, _ in _imports(mod):
            target = _own_target(name, attr)
            if target is not None and target != mod:
                edges[mod].add(target)
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one node (Tarjan), each with one cycle through it."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(set(edges) | {w for ws in edges.values() for w in ws}):
        if v not in index:
            visit(v)
    return found


def _describe(comp: list[str], edges: dict[str, set[str]]) -> str:
    """One cycle inside a component, as a → b → … → a, with where each import is."""
    inside = set(comp)
    path, seen = [comp[0]], {comp[0]}
    while True:
        nxt = sorted(w for w in edges[path[-1]] if w in inside)
        back = [w for w in nxt if w in seen]
        if back:
            path.append(back[0])
            path = path[path.index(back[0]):]
            break
        path.append(nxt[0])
        seen.add(nxt[0])
    return " → ".join(path) + f"  (component: {', '.join(comp)})"


def _where(src: str, dst: str, unit_level: bool = False) -> list[str]:
    """file:line of the imports from `src` (a module or unit) that reach `dst`."""
    out = []
    for mod in MODULES:
        if (_unit(mod) if unit_level else mod) != src:
            continue
        for name, attr, line in _imports(mod):
            target = _own_target(name, attr)
            if target is not None and (_unit(target) if unit_level else target) == dst:
                out.append(f"{MODULES[mod].relative_to(ROOT)}:{line}")
    return sorted(set(out))


def _cycle_report(edges: dict[str, set[str]], unit_level: bool) -> list[str]:
    """Each cycle of `edges`, with every import inside its component and where it is."""
    return [_describe(c, edges) + "\n      " + "; ".join(
        f"{a} → {b} at {', '.join(_where(a, b, unit_level))}" for a in c for b in sorted(edges[a] & set(c)))
        for c in _cycles(edges)]


def test_no_import_cycle_between_modules():
    report = _cycle_report(_edges(), unit_level=False)
    assert not report, "import cycles between modules:\n  " + "\n  ".join(report)


def test_no_import_cycle_between_subpackages():
    units: dict[str, set[str]] = defaultdict(set)
    for a, bs in _edges().items():
        for b in bs:
            if _unit(a) != _unit(b):
                units[_unit(a)].add(_unit(b))
    report = _cycle_report(units, unit_level=True)
    assert not report, "import cycles between subpackages:\n  " + "\n  ".join(report)


def test_every_unit_has_a_layer():
    missing = sorted({_unit(m) for m in MODULES} - set(RANK))
    assert not missing, f"add these to LAYERS in tests/test_layers.py and to docs/architecture.md: {missing}"


def test_no_upward_import():
    upward = []
    for mod in MODULES:
        src = _unit(mod)
        for name, attr, line in _imports(mod):
            target = _own_target(name, attr)
            if target is None or _unit(target) == src or src not in RANK or _unit(target) not in RANK:
                continue
            dst = _unit(target)
            if RANK[dst] > RANK[src]:
                upward.append(f"{MODULES[mod].relative_to(ROOT)}:{line}: {src} imports {dst} (a higher layer)")
    assert not upward, "upward imports:\n  " + "\n  ".join(upward)


def test_the_core_imports_no_io_package():
    bad = []
    for mod in MODULES:
        if not mod.startswith("prsm_sim"):
            continue
        for name, _, line in _imports(mod):
            if name.split(".")[0] in FORBIDDEN_IN_CORE:
                bad.append(f"{MODULES[mod].relative_to(ROOT)}:{line}: imports {name}")
    assert not bad, "prsm_sim imports I/O packages:\n  " + "\n  ".join(bad)


def test_no_private_name_imported_across_modules():
    bad = []
    for mod in MODULES:
        package = mod if _is_package(mod) else mod.rpartition(".")[0]
        for name, attr, line in _imports(mod):
            where = f"{MODULES[mod].relative_to(ROOT)}:{line}"
            private_parts = [p for p in name.split(".")[1:] if p.startswith("_") and not p.startswith("__")]
            own = name.split(".")[0] in PACKAGES
            if private_parts and not (own and name.rpartition(".")[0] == package):
                bad.append(f"{where}: imports from the private module {name}")
            if attr is None or not attr.startswith("_") or attr.startswith("__"):
                continue
            if own and f"{name}.{attr}" in MODULES and name == package:
                continue  # a package's private submodule, used inside that package
            bad.append(f"{where}: imports the private name {attr} from {name}")
    assert not bad, "private names imported across modules:\n  " + "\n  ".join(bad)


def test_the_checks_see_lazy_imports():
    """A function-local import is an import like any other; one for annotations only is not."""
    lazy = ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from prsm_sim.params import Params\n"
            "def f():\n    if True:\n        from prsm_sim.session import Session\n        import prsm_ros.bag\n")
    found = [(_own_target(n, a), line) for n, a, line in _imports("prsm_sim.errors", lazy)]
    assert found == [(None, 1), ("prsm_sim.session", 6), ("prsm_ros.bag", 7)]


def test_the_architecture_doc_shows_the_layer_table():
    """docs/architecture.md lists the units layer by layer as `LAYERS` orders them."""
    import re
    rows = [line for line in (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8").splitlines()
            if re.match(r"\| (core|I/O) \d+ \|", line)]
    doc = [tuple(re.findall(r"`([a-z_.]+)`", row.split("|")[2])) for row in rows]
    assert doc == list(LAYERS)


def _started_modules(mod: str, source: str | None = None) -> list[tuple[str, int]]:
    """(project module, line) that `mod` starts as a process by its name: `start_module("pkg.mod", …)`
    or `"-m", "pkg.mod"` in an argument list."""
    out = []
    tree = _tree(mod) if source is None else ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "start_module":
            args = node.args[:1]
        elif isinstance(node, (ast.List, ast.Tuple)):
            args = [b for a, b in zip(node.elts, node.elts[1:]) if isinstance(a, ast.Constant) and a.value == "-m"]
        else:
            continue
        out += [(a.value, node.lineno) for a in args
                if isinstance(a, ast.Constant) and isinstance(a.value, str) and a.value in MODULES]
    return out


def test_no_process_of_a_higher_layer_started_by_its_name():
    """A module starts (`python -m NAME`) only modules of its own or a lower layer: an entry point
    named by a string is an import the import checks cannot see (node replay starts the node's own
    `python -m prsm_ros.node`, not the CLI above it)."""
    bad = [f"{MODULES[mod].relative_to(ROOT)}:{line}: starts {started} ({_unit(started)} above {_unit(mod)})"
           for mod in MODULES for started, line in _started_modules(mod)
           if RANK[_unit(started)] > RANK[_unit(mod)]]
    assert not bad, "\n".join(bad)


def test_the_started_process_check_sees_a_string_entry_point():
    """Oracle for the check above: the old home of node replay (in `sweep`, starting the CLI) is found."""
    src = ('from prsm_ros.ros_env import start_module\nstart_module("prsm_ros.cli.node", [], {})\n'
           'subprocess.run([sys.executable, "-m", "prsm_ros.cli.ctl"])\n')
    found = _started_modules("prsm_ros.sweep", src)
    assert found == [("prsm_ros.cli.node", 2), ("prsm_ros.cli.ctl", 3)]
    assert all(RANK[_unit(m)] > RANK["prsm_ros.sweep"] for m, _ in found)
