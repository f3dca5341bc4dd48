"""The last command and what it answered: stays on screen until the next one (every screen has it)."""
from __future__ import annotations

from typing import Any

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static


class ReplyLine(Static):
    """Attributes: ``command``, ``text`` and ``ok`` of the last reply (``show`` sets them from the console's
    ``reply``)."""

    command: reactive[str] = reactive("")
    text: reactive[str] = reactive("")
    ok: reactive[bool] = reactive(True)

    def show(self, reply: Any) -> None:
        if reply is not None:
            self.command, self.ok, self.text = reply

    def render(self) -> Text:
        if not self.command:
            return Text(" replies to commands show here; 4: the log of every reply and event", style="dim")
        out = Text(f" {self.command} ", style="bold black on green" if self.ok else "bold white on red")
        out.append(f" {self.text}")
        out.no_wrap, out.overflow = True, "ellipsis"
        return out
