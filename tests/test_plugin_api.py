import sys
import textwrap

import pytest

from companion.cli.main import main
from companion.plugin_api import API_VERSION, PluginError, create, discover


@pytest.fixture
def third_party(tmp_path, monkeypatch):
    """A tiny third-party distribution with a good and a broken plugin, as pip installs it."""
    pkg = tmp_path / "acme_drivers"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            """
            class AcmeGripper:
                api_version = 1
                def __init__(self, pin=7):
                    self.pin = pin
                def start(self): pass
                async def release(self): pass
                def stop(self): pass

            class OldGripper:
                api_version = 0
            """
        )
    )
    (pkg / "broken.py").write_text("import this_module_does_not_exist\n")
    dist = tmp_path / "acme_drivers-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-drivers\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[companion.payloads]\n"
        "acme = acme_drivers:AcmeGripper\n"
        "acme_broken = acme_drivers.broken:Gripper\n"
        "acme_old = acme_drivers:OldGripper\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("acme_drivers", None)


def test_in_repo_plugins_are_discovered():
    cams, report = discover("companion.cameras")
    assert "opencv" in cams and all(r.ok for r in report if r.name == "opencv")
    pays, _ = discover("companion.payloads")
    assert "autopilot" in pays


def test_third_party_plugin_loads_and_broken_ones_are_reported_by_name(third_party):
    loaded, report = discover("companion.payloads")
    assert loaded["acme"].__name__ == "AcmeGripper" and "autopilot" in loaded
    by_name = {r.name: r for r in report}
    assert not by_name["acme_broken"].ok and "this_module_does_not_exist" in by_name["acme_broken"].error
    assert not by_name["acme_old"].ok and f"speaks {API_VERSION}" in by_name["acme_old"].error
    assert by_name["acme"].distribution == "acme-drivers"
    assert create("companion.payloads", "acme", pin=3).pin == 3
    with pytest.raises(PluginError, match="failed to load"):
        create("companion.payloads", "acme_broken")
    with pytest.raises(PluginError, match="no plugin"):
        create("companion.payloads", "nope")
    with pytest.raises(PluginError, match="unknown plugin group"):
        discover("companion.nothing")


def test_plugins_command_lists_everything(third_party, capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "opencv" in out and "acme " in out and "FAILED: ModuleNotFoundError" in out
    assert main(["plugins", "--strict"]) == 1
