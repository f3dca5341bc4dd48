"""The Log screen: every reply and every station event of this session, newest last (a scrollback)."""
from __future__ import annotations

from collections.abc import Iterable

from textual.app import ComposeResult
from textual.screen import Screen
from textual.widgets import Footer, Header, Label, RichLog

from fabric.tui.widgets.reply_line import ReplyLine


class LogScreen(Screen):
    """The console's log: the lines it held when the screen was first shown (``log_lines``), then each
    ``log_entry`` of the console as it comes."""

    def __init__(self, log_lines: Iterable[str] = ()) -> None:
        super().__init__()
        self.log_lines = log_lines

    def compose(self) -> ComposeResult:
        yield Header()
        yield Label(" replies and events, newest last (this session)", classes="section-title")
        yield RichLog(id="log", max_lines=2000, wrap=True, markup=False, highlight=False)
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        log = self.query_one(RichLog)
        for line in self.log_lines:
            log.write(line)
        self.watch(self.app, "log_entry", self._on_entry, init=False)
        self.watch(self.app, "reply", self.query_one(ReplyLine).show)

    def _on_entry(self, line: str) -> None:
        if line:
            self.query_one(RichLog).write(line)
