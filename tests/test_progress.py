"""The progress bar: drawn on a terminal only, a count and rate without a total, line ended."""

from __future__ import annotations

import io

import pytest

from avoidd import progress
from avoidd.progress import Progress


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_with_a_total_ends_its_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(progress, "_REDRAW_S", 0.0)
    screen = Terminal()
    bar = Progress(4, screen, width=8)
    for i in range(4):
        bar.step(f"frame {i}")
    assert "\r[##------] 1/4 frame 0" in screen.getvalue()
    assert screen.getvalue().endswith("\r[########] 4/4 frame 3" + " " * 33 + "\n")


def test_redraws_are_limited_but_the_last_step_always_draws() -> None:
    screen = Terminal()
    bar = Progress(1000, screen)
    for _ in range(1000):
        bar.step("x")
    text = screen.getvalue()
    assert text.count("\r") < 50  # 1000 steps in far less than 5 s
    assert "1000/1000" in text and text.endswith("\n")


def test_without_a_total_it_counts_and_close_ends_the_line() -> None:
    screen = Terminal()
    with Progress(None, screen) as bar:
        for _ in range(3):
            bar.step("pair")
    assert "3 done" in screen.getvalue() and "/s" in screen.getvalue()
    assert screen.getvalue().endswith("\n")


def test_nothing_is_drawn_when_the_stream_is_not_a_terminal() -> None:
    log = io.StringIO()
    with Progress(3, log) as bar:
        for _ in range(3):
            bar.step("x")
    assert log.getvalue() == ""
    assert not bar.active
