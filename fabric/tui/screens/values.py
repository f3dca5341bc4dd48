"""A dialog asking for bounded numbers (overrides, real-time factor, a layer): refused out of bounds."""
from __future__ import annotations

from typing import Any

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.validation import Integer, Number
from textual.widgets import Button, Input, Label

from fabric.tui.commands import Bound


class ValuesDialog(ModalScreen[dict[str, Any] | None]):
    """Dismissed with {name: value} for the filled fields (empty optional fields are left out), or None."""

    BINDINGS = [Binding("escape", "dismiss(None)", "cancel")]

    def __init__(self, title: str, bounds: tuple[Bound, ...], current: dict[str, float] | None = None) -> None:
        super().__init__()
        self.title_text, self.bounds, self.current = title, bounds, current or {}

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog"):
            yield Label(self.title_text, classes="dialog-title")
            for b in self.bounds:
                now = self.current.get(b.name)
                hint = f"{b.lo:g}..{b.hi:g} {b.unit}".rstrip() + (f", now {now:g}" if now is not None else "") \
                    + (", empty: keep" if b.optional else "")
                with Horizontal(classes="field"):
                    yield Label(f"{b.label}", classes="field-label")
                    validator = (Integer if b.integer else Number)(minimum=b.lo, maximum=b.hi)
                    yield Input(placeholder=hint, id=f"value-{b.name}", validators=[validator],
                                valid_empty=b.optional, type="integer" if b.integer else "number")
            yield Label("", id="value-error", classes="error")
            with Horizontal(classes="dialog-buttons"):
                yield Button("Cancel", id="cancel")
                yield Button("Apply", id="apply", variant="primary")

    def on_mount(self) -> None:
        self.query_one(Input).focus()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "apply":
            self.apply()
        else:
            self.dismiss(None)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.apply()

    def apply(self) -> None:
        values: dict[str, Any] = {}
        for b in self.bounds:
            field = self.query_one(f"#value-{b.name}", Input)
            raw = field.value.strip()
            result = field.validate(raw)
            if result is not None and not result.is_valid:
                self.query_one("#value-error", Label).update(
                    f"{b.label}: {raw or 'empty'} is not in {b.lo:g}..{b.hi:g}")
                field.focus()
                return
            if raw:
                values[b.name] = int(raw) if b.integer else float(raw)
        if not values and all(b.optional for b in self.bounds) and len(self.bounds) > 2:
            self.query_one("#value-error", Label).update("nothing to change")
            return
        self.dismiss(values)
