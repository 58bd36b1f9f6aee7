"""Every package folder in the repo is listed in pyproject (explicit list, mapped names)."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAP = {
    "sitl": "companion_sitl",
    "firmware": "companion_firmware",
    "lab": "companion_lab",
    "plugins": "companion_plugins",
    "params": "companion_params",
}


def test_every_package_is_installed():
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    for top in ("companion", *MAP):
        for init in (ROOT / top).rglob("__init__.py"):
            rel = init.parent.relative_to(ROOT).parts
            name = ".".join((MAP.get(rel[0], rel[0]), *rel[1:]))
            assert name in listed, f"{init.parent} is a package but {name} is not in pyproject packages"
    assert cfg["package-dir"] == {v: k for k, v in MAP.items()}
