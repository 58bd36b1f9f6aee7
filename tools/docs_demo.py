"""The demo's printed summary in README.md and docs/getting-started.md, from a run: the pages show
what `companion demo` prints (default parameters, seed 1), and tests/test_docs_demo_output.py
fails when a commit changes it without the pages.

    python tools/docs_demo.py           # fly the demo, rewrite both pages' example
    python tools/docs_demo.py --check   # fly it, exit 1 naming the lines that differ

The lines that depend on the machine (wall time) or the run (its folder) are compared without them.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# page -> (first line of its example, last line of its example)
PAGES = {
    ROOT / "README.md": ("DELIVERED", "  run folder"),
    ROOT / "docs" / "getting-started.md": ("companion demo:", "  scored reference"),
}
WALL = re.compile(r" / [0-9.]+ s \([0-9]+x real time\)$")  # "159.0 s / 8.42 s (19x real time)"


def demo_output() -> list[str]:
    """The lines `companion demo --quiet` prints with the default parameters, its run folder shown
    as runs/demo-<time>, as a user's run names it."""
    from companion.cli.main import main

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo"
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            code = main(["demo", "--quiet", "--out", str(out)])
        if code != 0:
            raise RuntimeError(f"companion demo exited {code}:\n{buf.getvalue()}")
        text = buf.getvalue().replace(str(out), "runs/demo-<time>")
    return [ln.rstrip() for ln in text.splitlines()]


def example_span(lines: list[str], first: str, last: str) -> tuple[int, int]:
    """Where the example lies in a page's lines: [start, end) between its fence lines."""
    start = next(i for i, ln in enumerate(lines) if ln.startswith(first))
    end = next(i for i in range(start, len(lines)) if lines[i].startswith(last)) + 1
    return start, end


def comparable(lines: list[str]) -> list[str]:
    """The lines without what differs between machines and runs."""
    return [WALL.sub(" / <wall>", ln) for ln in lines]


def expected(run: list[str], first: str, last: str) -> list[str]:
    start, end = example_span(run, first, last)
    return run[start:end]


def differences(run: list[str]) -> list[str]:
    """For each page, the example lines that differ from the run (empty: all agree)."""
    out = []
    for page, (first, last) in PAGES.items():
        lines = page.read_text(encoding="utf-8").splitlines()
        start, end = example_span(lines, first, last)
        want, have = comparable(expected(run, first, last)), comparable(lines[start:end])
        if want != have:
            rel = page.relative_to(ROOT)
            pairs = zip(have, want, strict=False)  # a length difference is said below
            out += [f"{rel}: the page shows {h!r}, the demo prints {w!r}" for h, w in pairs if h != w]
            if len(want) != len(have):
                out.append(f"{rel}: {len(have)} lines on the page, {len(want)} printed")
    return out


def rewrite(run: list[str]) -> None:
    for page, (first, last) in PAGES.items():
        text = page.read_text(encoding="utf-8")
        lines = text.splitlines()
        start, end = example_span(lines, first, last)
        lines[start:end] = expected(run, first, last)
        page.write_text("\n".join(lines) + ("\n" if text.endswith("\n") else ""), encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only compare; exit 1 when a page differs")
    args = ap.parse_args(argv)
    run = demo_output()
    if args.check:
        diff = differences(run)
        print("\n".join(diff) or "both pages show what the demo prints")
        return 1 if diff else 0
    rewrite(run)
    return 0


if __name__ == "__main__":
    sys.exit(main())
