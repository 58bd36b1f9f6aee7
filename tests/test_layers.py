"""The layer order of the project, checked on its import graph (docs/architecture.md).

Every import in every module (function-level ones included) is parsed with :mod:`ast` and
mapped to the unit it lands in: a subpackage of ``companion`` or one of the packages beside it
(the simulator, the firmware harnesses, the experiment tooling, the driver plugins). An edge
between two units must be listed in ``ALLOWED`` below, the one place the layer order is written
down. Inside a unit, the modules' own import graph must have no cycle.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "companion"
# installed name -> folder in the repository (pyproject's package-dir)
OUTSIDE = {
    "companion_sitl": ROOT / "sitl",
    "companion_firmware": ROOT / "firmware",
    "companion_lab": ROOT / "lab",
    "companion_plugins": ROOT / "plugins",
}
SIMULATOR = "companion_sitl"
TOOLING = {"companion_sitl", "companion_firmware", "companion_lab"}

# Lowest first. "companion" is the package's own __init__ (the version string).
BASE = {
    "companion",
    "geometry",
    "config",
    "param_kinds",
    "events",
    "scheduling",
    "plugin_api",
    "units",
    "foxglove_schemas",
    "timebase",
    "secret_files",
}
CORE = BASE | {"vision", "uwb", "estimation", "guidance", "autopilot", "telemetry", "flightlog", "delivery", "dart"}

# unit -> the units it may import (besides itself). The layer picture, written once:
#   9  cli                                   (companion's command line)
#   8  companion_lab                         experiment tooling: demo, campaigns, parity, benches
#   7  companion_firmware                    real-firmware harnesses (PX4 SIH, ArduCopter SITL)
#   6  companion_sitl                        the embedded simulator
#   5  delivery   dart                       (the two applications, side by side)
#   4  telemetry  flightlog
#   3  autopilot
#   2  vision  uwb  estimation  guidance
#   1  geometry  config (param_kinds)  events  scheduling  plugin_api  units  foxglove_schemas  timebase
#      secret_files
#   companion_plugins (real drivers) sit beside the applications and import only the core.
ALLOWED: dict[str, set[str]] = {
    "companion": set(),
    "geometry": set(),
    "config": {"geometry"},  # the fence polygons are checked at load (geometry.polygon)
    "param_kinds": {"config"},
    "events": set(),
    "scheduling": set(),
    "plugin_api": set(),
    "units": set(),
    "foxglove_schemas": set(),  # Foxglove schemas and conventions, shared by flightlog and telemetry
    "timebase": set(),  # the vehicle clock signed requests are judged on, and the pre-flight verdict on it
    "secret_files": {"config"},  # secret files read only when no one but their owner can read or write them
    "vision": {"geometry", "config"},  # its parameters' schema (config.py)
    "uwb": {"geometry", "config"},
    "estimation": {"geometry", "config", "param_kinds"},  # the Dart filters' schemas (param_kinds.py)
    "guidance": {"geometry", "config"},
    "autopilot": {"geometry", "config", "estimation", "guidance", "timebase", "secret_files"},
    "telemetry": {
        "companion",
        "config",
        "events",
        "units",
        "autopilot",
        "estimation",
        "foxglove_schemas",
        "timebase",
        "secret_files",
    },
    "flightlog": {"geometry", "units", "autopilot", "guidance", "foxglove_schemas"},
    "delivery": BASE | {"vision", "uwb", "estimation", "guidance", "autopilot", "telemetry", "flightlog"},
    "dart": BASE | {"vision", "estimation", "autopilot", "flightlog"},
    "companion_sitl": CORE,
    "companion_firmware": CORE | {"companion_sitl"},
    "companion_lab": CORE | {"companion_sitl", "companion_firmware"},
    "companion_plugins": CORE,
    "cli": CORE | TOOLING,
    "__main__": {"cli"},  # `python -m companion`: the command line and nothing else
}


def _files() -> Iterator[tuple[str, Path, Path]]:
    """(package name, package folder, file) of every module of ours."""
    for name, folder in (("companion", PACKAGE), *OUTSIDE.items()):
        for path in sorted(folder.rglob("*.py")):
            yield name, folder, path


def _module_name(path: Path) -> str:
    for name, folder in (("companion", PACKAGE), *OUTSIDE.items()):
        if path.is_relative_to(folder):
            parts = (name, *path.relative_to(folder).with_suffix("").parts)
            return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
    raise AssertionError(f"{path} is in none of our packages")


def _package_of(module: str) -> str | None:
    """The layer unit of a module name: ``companion.vision.pad`` -> ``vision``; None if not ours."""
    parts = module.split(".")
    if parts[0] in OUTSIDE:
        return parts[0]
    if parts[0] != "companion":
        return None
    return parts[1] if len(parts) > 1 else "companion"


def _imports(path: Path) -> Iterator[tuple[int, str]]:
    """(line, absolute module name) of every import in the file, nested ones included."""
    module = _module_name(path)
    here = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = here[: len(here) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if target == "companion":  # `from companion import cli` imports a package, `__version__` does not
                subs = [a.name for a in node.names if any((PACKAGE / n).exists() for n in (a.name, f"{a.name}.py"))]
                for name in subs:
                    yield node.lineno, f"companion.{name}"
                if len(subs) == len(node.names):
                    continue
            yield node.lineno, target


def _edges() -> Iterator[tuple[str, int, str, str]]:
    """(file, line, from package, to package) of every import that leaves its package."""
    for _, _, path in _files():
        src = _package_of(_module_name(path))
        assert src is not None
        for line, target in _imports(path):
            dst = _package_of(target)
            if dst is None or dst == src:
                continue
            yield str(path.relative_to(ROOT)), line, src, dst


def test_every_package_has_a_place_in_the_layers() -> None:
    found = {_package_of(_module_name(p)) for _, _, p in _files()}
    unknown = sorted(p for p in found if p not in ALLOWED)
    assert not unknown, f"packages/modules of companion with no place in ALLOWED: {unknown}"


def test_imports_follow_the_layer_order() -> None:
    bad = [
        f"{file}:{line}: {src} imports {dst}"
        for file, line, src, dst in _edges()
        if src in ALLOWED and dst not in ALLOWED[src]
    ]
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_the_application_never_imports_the_simulator_or_the_tooling() -> None:
    bad = [f"{file}:{line}: {src} imports {dst}" for file, line, src, dst in _edges() if dst in TOOLING and src in CORE]
    assert not bad, "\n".join(bad)


def _module_graph() -> dict[str, dict[str, set[str]]]:
    """unit -> module -> the modules of the same unit it imports (function-level imports included)."""
    known = {_module_name(p) for _, _, p in _files()}
    graph: dict[str, dict[str, set[str]]] = {}
    for _, _, path in _files():
        mod = _module_name(path)
        unit = _package_of(mod)
        assert unit is not None
        edges = graph.setdefault(unit, {}).setdefault(mod, set())
        for _, target in _imports(path):
            # `from pkg import name` may name a submodule
            while target and target not in known:
                target = target.rpartition(".")[0]
            if target and target != mod and _package_of(target) == unit and not mod.startswith(target + "."):
                edges.add(target)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[str]:
    """Every cycle a depth-first walk of ``graph`` meets, as ``a -> b -> a``."""
    cycles: list[str] = []
    state: dict[str, int] = {}

    def visit(m: str, stack: tuple[str, ...]) -> None:
        if state.get(m) == 2:
            return
        if state.get(m) == 1:
            cycles.append(" -> ".join((*stack[stack.index(m) :], m)))
            return
        state[m] = 1
        for q in sorted(graph.get(m, set())):
            visit(q, (*stack, m))
        state[m] = 2

    for m in sorted(graph):
        visit(m, ())
    return cycles


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a -> b -> c -> a"]
    assert _cycles({"a": {"b", "c"}, "b": {"c"}, "c": set()}) == []


def test_no_import_cycle_inside_a_package() -> None:
    cycles = [c for graph in _module_graph().values() for c in _cycles(graph)]
    assert not cycles, "import cycles inside a package:\n" + "\n".join(cycles)
