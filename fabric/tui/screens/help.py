"""Every key of the console, in one dialog (lines short enough for an 80-column terminal)."""
from __future__ import annotations

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import ModalScreen
from textual.widgets import Label, Static

KEYS = """\
screens   1 cell  2 jobs  3 events  4 log  5 files  g other cells
          ? keys  q or ctrl+c quit
start     a submit a file (the bundled samples are listed there)
          e preheat (PLA, PETG, ABS, TPU, cool down)
print     s start (a layer, sim speed)  p pause  r resume
          x stop*  v recover (after a crash)
          o overrides (speed, flow, nozzle, bed)  f sim speed
robot     h home*  k calibrate*  j jog  E extrude by hand (hot nozzle)
ask       y ready?  c collisions  w position  t time
jobs      n next job (plate clear?)*  del remove*  R print again
          [ ] move in the queue  enter the whole record
files     R print again  del forget*  enter details  u refresh
events    / search  pick a kind in the list
                                             * asks first"""


class HelpDialog(ModalScreen[None]):
    BINDINGS = [Binding("escape,question_mark,q,enter", "dismiss", "close")]

    def compose(self) -> ComposeResult:
        with VerticalScroll(classes="dialog"):
            yield Label("Keys", classes="dialog-title")
            yield Static(KEYS, markup=False)
