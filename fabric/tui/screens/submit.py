"""Submit a print job: a model (STL, 3MF, OBJ) or G-code from a file picker or the bundled samples, with the
slicer's back-ends, profiles and layers (planar, or curved with a tilted nozzle)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.validation import Number
from textual.widgets import Button, Checkbox, DirectoryTree, Input, Label, Select

from fabric.samples import samples
from fabric.tui.widgets.model_tree import PRINTABLE_SUFFIXES, ModelTree

DEFAULT_RTF = 1.0          # the real-time factor when the field is left empty (real time)


@dataclass(frozen=True)
class SubmitChoice:
    """What the operator chose: the file, how to slice it, and whether to start once loaded."""

    path: Path
    backend: str
    profile: str
    start: bool
    rtf: float
    layers: str = "planar"       # planar, or curved layers with a tilted nozzle (a model, builtin slicer)


class SubmitDialog(ModalScreen[SubmitChoice | None]):
    BINDINGS = [Binding("escape", "dismiss(None)", "cancel")]

    def __init__(self, root: Path, backends: dict[str, str], profiles: list[str]) -> None:
        super().__init__()
        self.root = root
        self.backends = {name: version for name, version in backends.items() if version} or {"builtin": "?"}
        self.profiles = profiles or ["taz-pla-medium"]
        self.samples = {str(x.path): x for x in samples()}

    def compose(self) -> ComposeResult:
        with Vertical(classes="dialog", id="submit-dialog"):
            yield Label("Submit a print job: an STL, 3MF, OBJ or G-code file", classes="dialog-title")
            yield ModelTree(self.root, id="submit-tree")
            yield Input(placeholder="file path (pick one above, or a sample below)", id="submit-path")
            with Horizontal(classes="field"):
                yield Select([(f"{x.name} ({x.size_mm[2]:.0f} mm)", key) for key, x in self.samples.items()],
                             prompt="samples", id="submit-sample")
                yield Select([(f"{n} {v}", n) for n, v in self.backends.items()], value=next(iter(self.backends)),
                             allow_blank=False, id="submit-backend")
                yield Select([(p, p) for p in self.profiles], value=self.profiles[0], allow_blank=False,
                             id="submit-profile")
            with Horizontal(classes="field"):
                yield Checkbox("start once loaded", value=True, id="submit-start")
                yield Select([("planar layers", "planar"), ("curved layers", "curved")], value="planar",
                             allow_blank=False, id="submit-layers")
                yield Input(placeholder=f"sim speed (0 = max, empty = {DEFAULT_RTF:g})", id="submit-rtf",
                            validators=[Number(minimum=0, maximum=1e6)], type="number", valid_empty=True)
            with Horizontal(classes="dialog-buttons"):
                yield Label("", id="submit-error", classes="error")
                yield Button("Cancel", id="cancel")
                yield Button("Submit", id="submit", variant="primary")

    def on_mount(self) -> None:
        self.query_one(ModelTree).focus()

    def on_directory_tree_file_selected(self, event: DirectoryTree.FileSelected) -> None:
        self.query_one("#submit-path", Input).value = str(event.path)

    def on_select_changed(self, event: Select.Changed) -> None:
        if event.select.id == "submit-sample" and isinstance(event.value, str):
            self.query_one("#submit-path", Input).value = event.value

    def on_input_changed(self, event: Input.Changed) -> None:
        """A new path or sim speed: the complaint about the last one goes (it read "pick a file" after one was)."""
        self.query_one("#submit-error", Label).update("")

    def on_input_submitted(self, event: Input.Submitted) -> None:
        self.submit()

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "submit":
            self.submit()
        else:
            self.dismiss(None)

    def submit(self) -> None:
        error = self.query_one("#submit-error", Label)
        path = Path(self.query_one("#submit-path", Input).value.strip()).expanduser()
        if not path.is_file() or path.suffix.lower() not in PRINTABLE_SUFFIXES:
            error.update(f"pick a file ({', '.join(PRINTABLE_SUFFIXES)})")
            return
        rtf_in = self.query_one("#submit-rtf", Input)
        raw = rtf_in.value.strip()
        checked = rtf_in.validate(raw)          # None: empty (allowed), or no validator
        if checked is not None and not checked.is_valid:
            error.update("the sim speed is 0..1e6 x real time (0 = as fast as possible)")
            return
        self.dismiss(SubmitChoice(path, str(self.query_one("#submit-backend", Select).value),
                                  str(self.query_one("#submit-profile", Select).value),
                                  self.query_one("#submit-start", Checkbox).value,
                                  float(raw) if raw else DEFAULT_RTF,
                                  str(self.query_one("#submit-layers", Select).value)))
