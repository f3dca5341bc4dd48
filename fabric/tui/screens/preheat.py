"""Preheat: the set points of a material in one key (or both heaters off)."""
from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Label, OptionList
from textual.widgets.option_list import Option

from fabric.tui.commands import Preset


class PreheatDialog(ModalScreen[Preset | None]):
    BINDINGS = [Binding("escape", "dismiss(None)", "cancel")]

    def __init__(self, presets: tuple[Preset, ...]) -> None:
        super().__init__()
        self.presets = presets

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Label("Preheat (nozzle / bed set points)", classes="dialog-title")
            yield OptionList(*[Option(f"{p.name:<10} nozzle {p.nozzle_c:3.0f} C   bed {p.bed_c:3.0f} C"
                                      if p.nozzle_c or p.bed_c else f"{p.name:<10} both heaters off", id=str(i))
                               for i, p in enumerate(self.presets)], id="preheat-list")
            yield Label("a print's own G-code sets its temperatures when it starts", classes="hint")

    def on_option_list_option_selected(self, event: OptionList.OptionSelected) -> None:
        self.dismiss(self.presets[int(event.option.id or 0)])
