"""The cells present on the fabric (from liveliness tokens); pick one to follow."""
from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Label, OptionList
from textual.widgets.option_list import Option

from fabric.wire.keys import SERVICES


class CellsDialog(ModalScreen[str | None]):
    BINDINGS = [Binding("escape", "dismiss(None)", "cancel")]

    def __init__(self, cells: dict[str, list[str]], current: str) -> None:
        super().__init__()
        self.cells, self.current = cells, current

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Label("Cells on the fabric", classes="dialog-title")
            if not self.cells:
                yield Label("no cell answers on this hub")
            yield OptionList(*[Option(f"{'▶' if name == self.current else ' '} {name:<16} "
                                      f"{len(services)}/{len(SERVICES)} services", id=name)
                               for name, services in self.cells.items()], id="cells-list")

    def on_option_list_option_selected(self, event: OptionList.OptionSelected) -> None:
        self.dismiss(event.option.id)
