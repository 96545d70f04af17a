"""Progress without a terminal (a log file, CI): a line of its own per redraw, with how far, the
rate and the time left; nothing at all from a run shorter than the first interval."""

from __future__ import annotations

import time

from trainclimate.cli import common


def test_progress_lines_when_stderr_is_not_a_terminal(monkeypatch, capsys):
    monkeypatch.setattr(common, "PROGRESS_LINE_EVERY_S", 0.0)
    with common.progress_bar(3, "fits", "fit") as bar:
        for _ in range(3):
            time.sleep(0.01)
            bar.update(1)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) >= 2 and "\r" not in "".join(lines)
    assert lines[-1].startswith("fits: 100%") and "3/3 [" in lines[-1]
    assert all(line.startswith("fits:") for line in lines)


def test_a_short_run_prints_no_progress(capsys):
    with common.progress_bar(3, "fits", "fit") as bar:
        bar.update(3)
    assert capsys.readouterr().err == ""
