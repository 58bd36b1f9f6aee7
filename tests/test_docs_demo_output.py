"""README.md and docs/getting-started.md show what `companion demo` prints (tools/docs_demo.py
rewrites them from a run): a commit that changes the demo's figures changes the pages too."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / "tools" / "docs_demo.py"


def _tool():  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("docs_demo", TOOL)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.flight
def test_the_pages_show_what_the_demo_prints():
    tool = _tool()
    diff = tool.differences(tool.demo_output())
    assert not diff, "run `python tools/docs_demo.py` to rewrite the pages:\n" + "\n".join(diff)


def test_a_changed_figure_is_found_and_the_wall_time_is_not_compared():
    tool = _tool()
    page = TOOL.parents[1] / "README.md"
    lines = page.read_text(encoding="utf-8").splitlines()
    start, end = tool.example_span(lines, *tool.PAGES[page])
    shown = lines[start:end]
    run = [tool.WALL.sub(" / 99.00 s (2x real time)", ln) for ln in shown]  # another machine's wall time
    assert run != shown and tool.comparable(run) == tool.comparable(shown)
    moved = [ln.replace("DELIVERED, returned home", "NOT DELIVERED") for ln in shown]
    assert tool.comparable(moved) != tool.comparable(shown)
