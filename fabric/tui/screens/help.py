"""Every key of the console, in one dialog."""
from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Label, Static

KEYS = """\
1 cell   2 jobs   3 events   g cells on the fabric   ? this help   q quit

station   s start (layer, rtf)   p pause   r resume   v recover (after a crash)
          x stop*   h home*   k calibrate*   (* asks first)
          o overrides (speed, flow, nozzle, bed)   f simulation speed (rtf)
          y ready?   c collisions   w position   t time

jobs      a submit a file   n next job (plate clear)   del remove*
          [ / ] move up / down in the queue   enter the whole record
events    / search   pick a kind in the list   live events are added as they come"""


class HelpDialog(ModalScreen[None]):
    BINDINGS = [Binding("escape,question_mark,q,enter", "dismiss", "close")]

    def compose(self) -> ComposeResult:
        with VerticalScroll(classes="dialog"):
            yield Label("Keys", classes="dialog-title")
            yield Static(KEYS, markup=False)
