"""The layer order of ``companion``, checked on its import graph (docs/architecture.md).

Every import in every module (function-level ones included) is parsed with :mod:`ast` and
mapped to the package it lands in; an edge between two packages must be listed in
``ALLOWED`` below, the one place the layer order is written down. Imports inside a package are
free. Only ``companion.cli`` may import the simulator (``companion_sitl``).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "companion"

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
}

# package -> the packages it may import (besides itself). The layer picture, written once:
#   6  cli
#   5  delivery   dart                      (the two applications, side by side)
#   4  telemetry  flightlog
#   3  autopilot
#   2  vision  uwb  estimation  guidance
#   1  geometry  config (param_kinds)  events  scheduling  plugin_api  units  foxglove_schemas
ALLOWED: dict[str, set[str]] = {
    "companion": set(),
    "geometry": set(),
    "config": set(),
    "param_kinds": {"config"},
    "events": set(),
    "scheduling": set(),
    "plugin_api": set(),
    "units": set(),
    "foxglove_schemas": set(),  # Foxglove schemas and conventions, shared by flightlog and telemetry
    "vision": {"geometry"},
    "uwb": {"geometry"},
    "estimation": {"geometry"},
    "guidance": {"geometry", "config"},
    "autopilot": {"geometry", "config", "estimation", "guidance"},
    "telemetry": {"companion", "config", "events", "units", "autopilot", "estimation", "foxglove_schemas"},
    "flightlog": {"geometry", "units", "autopilot", "guidance", "foxglove_schemas"},
    "delivery": BASE | {"vision", "uwb", "estimation", "guidance", "autopilot", "telemetry", "flightlog"},
    "dart": BASE | {"vision", "estimation", "autopilot", "flightlog"},
    "cli": BASE
    | {"vision", "uwb", "estimation", "guidance", "autopilot", "telemetry", "flightlog", "delivery", "dart"}
    | {"companion_sitl"},
    "__main__": {"cli"},  # `python -m companion`: the command line and nothing else
}
SIMULATOR = "companion_sitl"


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _package_of(module: str) -> str | None:
    """The layer unit of a module name: ``companion.vision.pad`` -> ``vision``; None if not ours."""
    parts = module.split(".")
    if parts[0] == SIMULATOR:
        return SIMULATOR
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
    for path in sorted(PACKAGE.rglob("*.py")):
        src = _package_of(_module_name(path))
        assert src is not None
        for line, target in _imports(path):
            dst = _package_of(target)
            if dst is None or dst == src:
                continue
            yield str(path.relative_to(ROOT)), line, src, dst


def test_every_package_has_a_place_in_the_layers() -> None:
    found = {_package_of(_module_name(p)) for p in PACKAGE.rglob("*.py")}
    unknown = sorted(p for p in found if p not in ALLOWED)
    assert not unknown, f"packages/modules of companion with no place in ALLOWED: {unknown}"


def test_imports_follow_the_layer_order() -> None:
    bad = [
        f"{file}:{line}: {src} imports {dst}"
        for file, line, src, dst in _edges()
        if src in ALLOWED and dst not in ALLOWED[src]
    ]
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_only_the_cli_imports_the_simulator() -> None:
    bad = [f"{file}:{line}: {src} imports {dst}" for file, line, src, dst in _edges() if dst == SIMULATOR]
    assert all(" cli imports " in b for b in bad), "\n".join(b for b in bad if " cli imports " not in b)


def test_the_allowed_edges_have_no_cycle() -> None:
    order: list[str] = []
    state: dict[str, int] = {}

    def visit(p: str, stack: tuple[str, ...]) -> None:
        if state.get(p) == 2:
            return
        assert state.get(p) != 1, f"cycle in ALLOWED: {' -> '.join((*stack, p))}"
        state[p] = 1
        for q in sorted(ALLOWED.get(p, set())):
            visit(q, (*stack, p))
        state[p] = 2
        order.append(p)

    for p in sorted(ALLOWED):
        visit(p, ())
    assert SIMULATOR in order
