"""Services panel: one line per service, alive or dead."""
from __future__ import annotations

from textual.reactive import reactive
from textual.widgets import Static

from fabric.keys import SERVICES


class ServicesPanel(Static):
    alive: reactive[dict] = reactive(dict, always_update=True)

    def render(self) -> str:
        lines = ["[b]services[/b]"]
        for name in SERVICES:
            up = self.alive.get(name, False)
            lines.append(f"{'[green]●[/green]' if up else '[red]○[/red]'} {name:<11} {'alive' if up else 'DOWN'}")
        return "\n".join(lines)
