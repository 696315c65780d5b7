"""The quick benchmarks of ``make bench`` (``benchmarks/quick.txt``): each line names a
script of ``benchmarks/``, and the script accepts the options the line gives it.

Cheap by design: each script runs with its line's arguments followed by ``--help``, so
argparse converts the given values (a bad value fails) and prints its help instead of
measuring; every option of the line must appear in that help (a misspelled or removed
option fails). Whether the benchmark itself still runs is ``make bench``'s check.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
QUICK = REPO / "benchmarks" / "quick.txt"


def quick_lines() -> list[list[str]]:
    """The commands of ``quick.txt``, split on spaces as the Makefile's loop splits them."""
    lines = QUICK.read_text(encoding="utf-8").splitlines()
    return [line.split() for line in lines if line.strip() and not line.startswith("#")]


def test01_lists_existing_scripts_once() -> None:
    lines = quick_lines()
    assert lines, "benchmarks/quick.txt lists no benchmark"
    scripts = [words[0] for words in lines]
    for script in scripts:
        assert script.startswith("bench_") and script.endswith(".py"), script
        assert (REPO / "benchmarks" / script).is_file(), f"benchmarks/{script} does not exist"
    assert len(set(scripts)) == len(scripts), "a script is listed twice"


@pytest.mark.parametrize("words", quick_lines(), ids=lambda w: w[0])
def test02_script_accepts_its_options(words: list[str]) -> None:
    script, args = words[0], words[1:]
    out = subprocess.run(
        [sys.executable, str(REPO / "benchmarks" / script), *args, "--help"],
        cwd=REPO,  # as `make bench` runs it
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("usage:"), out.stdout[:500]
    for option in (a for a in args if a.startswith("--")):
        assert option in out.stdout, f"{script}: {option} is not one of its options"
