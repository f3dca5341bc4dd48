"""The last command and what it answered: stays on screen until the next one."""
from __future__ import annotations

from rich.text import Text
from textual.reactive import reactive
from textual.widgets import Static


class ReplyLine(Static):
    """Attributes: ``command``, ``text`` and ``ok`` of the last reply."""

    command: reactive[str] = reactive("")
    text: reactive[str] = reactive("")
    ok: reactive[bool] = reactive(True)

    def render(self) -> Text:
        if not self.command:
            return Text(" ? keys  1 cell  2 jobs  3 events  g cells", style="dim")
        out = Text(f" {self.command} ", style="bold black on green" if self.ok else "bold white on red")
        out.append(f" {self.text}")
        out.no_wrap, out.overflow = True, "ellipsis"
        return out
