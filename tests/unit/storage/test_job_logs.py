"""Per-job logs (:mod:`storage.job_logs`): appended lines, the tail, the size cap.

Oracles: the file's bytes read back with plain ``open``; the cap checked against
``os.stat``; the documented marker line."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from storage.job_logs import JobLog, log_dir

JOB = "0123456789abcdef0123456789abcdef"


def test01_lines_are_appended_stamped_and_tailed(tmp_path: Path) -> None:
    log = JobLog(log_dir(tmp_path), JOB)
    assert log.read() == "" and log.read(5) == ""  # nothing logged yet: empty, no error
    log.write("first")
    log.write("second\nthird\n")
    raw = (tmp_path / "logs" / f"{JOB}.log").read_text()
    lines = raw.splitlines()
    assert [ln.split(" ", 1)[1] for ln in lines] == ["first", "second", "third"]
    assert all(ln[:4].isdigit() and ln[19] == "Z" for ln in lines)  # 2026-12-02T10:00:00Z
    assert log.read() == raw
    assert log.read(2) == "".join(raw.splitlines(keepends=True)[-2:])
    assert log.read(0) == ""


def test02_the_log_stops_at_its_cap_with_one_marker(tmp_path: Path) -> None:
    cap = 4096
    log = JobLog(tmp_path, JOB, max_bytes=cap)
    for i in range(500):
        log.write(f"line {i:04d} " + "x" * 40)
    text = log.read()
    size = os.stat(log.path).st_size
    assert size <= cap, size
    assert text.count("[log truncated") == 1 and text.endswith("later lines were dropped]\n")
    assert "line 0000" in text and "line 0499" not in text
    log.write("after the cap")
    assert log.read() == text  # full: nothing more is written
    # One huge message is cut to a quarter of the cap, so it cannot end the log alone.
    other = JobLog(tmp_path, JOB.replace("0", "f"), max_bytes=cap)
    other.write("y" * (10 * cap))
    assert os.stat(other.path).st_size <= cap // 4 + 64 and other.read().endswith("[... cut]\n")
    other.write("next")
    assert other.read().endswith(" next\n")


def test03_never_raises_and_refuses_a_path_for_an_id(tmp_path: Path) -> None:
    (tmp_path / "logs").write_text("a file where the directory should be")
    JobLog(tmp_path / "logs", JOB).write("lost, silently")  # must not fail a job
    for bad in ("../../etc/passwd", JOB[:8], JOB.upper()):
        with pytest.raises(ValueError, match="not a full job id"):
            JobLog(tmp_path, bad)
