"""The CLI's progress line: redrawn in place on a terminal, a plain line per stage when piped (logs, CI)."""
from __future__ import annotations

import io

from fabric.cli.output import StatusLine


def test_on_a_terminal_the_line_is_redrawn_and_ended_once() -> None:
    out = io.StringIO()
    with StatusLine(out, tty=True) as line:
        for pct in (0.0, 42.5, 100.0):
            line.draw(f"  planning {pct:5.1f} %", piped="  planning")
    text = out.getvalue()
    assert text == "\r  planning   0.0 %\r  planning  42.5 %\r  planning 100.0 %\n"


def test_piped_each_stage_is_one_line_without_carriage_returns() -> None:
    out = io.StringIO()
    with StatusLine(out, tty=False) as line:
        for stage, pct in (("slicing", 0.0), ("slicing", 51.5), ("planning", 0.0), ("planning", 85.0)):
            line.draw(f"  {stage:<20} {pct:5.1f} %", piped=f"  {stage}")
    assert out.getvalue() == "  slicing\n  planning\n"


def test_piped_without_a_piped_text_prints_each_change_once() -> None:
    out = io.StringIO()
    with StatusLine(out, tty=False) as line:
        for text in ("  queued     waiting   ", "  queued     waiting   ", "  printing   layer 1"):
            line.draw(text)
    assert out.getvalue() == "  queued     waiting\n  printing   layer 1\n"


def test_nothing_drawn_prints_nothing() -> None:
    out = io.StringIO()
    with StatusLine(out, tty=True):
        pass
    assert out.getvalue() == ""
