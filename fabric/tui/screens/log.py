"""The Log screen: every reply and every station event of this session, newest last (a scrollback)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from textual.app import ComposeResult
from textual.screen import Screen
from textual.widgets import Footer, Header, Label, RichLog

from fabric.tui.widgets.reply_line import ReplyLine

if TYPE_CHECKING:
    from textual import getters

    from fabric.tui.app import FabricConsole


class LogScreen(Screen):
    """Reads the console's log (``log_lines``, then each ``log_entry`` as it comes)."""

    if TYPE_CHECKING:
        app = getters.app(FabricConsole)      # self.app is the console (for the type checker)

    def compose(self) -> ComposeResult:
        yield Header()
        yield Label(" replies and events, newest last (this session)", classes="section-title")
        yield RichLog(id="log", max_lines=2000, wrap=True, markup=False, highlight=False)
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        log = self.query_one(RichLog)
        for line in self.app.log_lines:
            log.write(line)
        self.watch(self.app, "log_entry", self._on_entry, init=False)
        self.watch(self.app, "reply", self.query_one(ReplyLine).show)

    def _on_entry(self, line: str) -> None:
        if line:
            self.query_one(RichLog).write(line)
