"""The Events screen: the station's event history plus the live stream, filtered by kind, searchable."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Header, Input, Label, Select

from fabric import schemas as s
from fabric.sim.types import EVENT_KINDS
from fabric.tui.format import event_data_text
from fabric.tui.messages import Reply
from fabric.tui.widgets.reply_line import ReplyLine
from fabric.wire.errors import FabricError

if TYPE_CHECKING:
    from fabric.client import Client

HISTORY_EVENTS = 5000      # the newest this many events are fetched


class EventsScreen(Screen):
    """Watches the console's client (the cell followed: its history is read again) and its last event."""

    BINDINGS = [Binding("slash", "search", "search", show=False),
                Binding("escape", "clear", "clear filter", show=False)]

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[s.Event] = []
        self.kind: str | None = None
        self.client: Client | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        with Horizontal(id="events-filter"):
            yield Select([(k, k) for k in EVENT_KINDS], prompt="every kind", id="events-kind")
            yield Input(placeholder="/ search (kind, reason, any data)", id="events-search")
        yield Label("", id="events-count")
        yield DataTable(id="events-table", cursor_type="row", zebra_stripes=True)
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one(DataTable).add_columns("seq", "t_sim s", "kind", "layer", "line", "data")
        self.watch(self.app, "last_event", self._on_event, init=False)
        self.watch(self.app, "client", self._on_client)
        self.watch(self.app, "reply", self.query_one(ReplyLine).show)

    def _on_client(self, client: Client | None) -> None:
        self.client = client
        self.load(self.kind)            # the cell followed (first, or the one the console switched to): its history

    def _on_event(self, e: Any) -> None:
        if (e is not None and (self.kind is None or e.kind == self.kind)
                and (not self.rows or e.seq > self.rows[-1].seq)):
            self.rows.append(e)
            if self._matches(e, self._search()):
                self.query_one(DataTable).add_row(*self._cells(e))
                self._count()

    # --- history ----------------------------------------------------------------------

    @work(thread=True, exclusive=True, group="events-history")
    def load(self, kind: str | None) -> None:
        client = self.client
        if client is None:
            return
        try:
            last = client.events(since_seq=1 << 62, limit=1).last_seq
            evs = client.events(max(0, last - HISTORY_EVENTS), limit=HISTORY_EVENTS + 100,
                                kinds=[kind] if kind else None).events
        except FabricError as err:
            self.post_message(Reply("events", False, err.message))
            return
        self.app.call_from_thread(self.show_events, kind, evs)

    def show_events(self, kind: str | None, events: list[s.Event]) -> None:
        """Replace the rows (history of one kind, or of all) and redraw."""
        if kind != self.kind:
            return
        seen = {e.seq for e in events}
        live = [e for e in self.rows if e.seq not in seen and e.seq > (events[-1].seq if events else 0)]
        self.rows = list(events) + live
        self.redraw()

    def redraw(self) -> None:
        table = self.query_one(DataTable)
        table.clear()
        text = self._search()
        for e in self.rows:
            if self._matches(e, text):
                table.add_row(*self._cells(e))
        table.move_cursor(row=max(0, table.row_count - 1))
        self._count()

    # --- filters ----------------------------------------------------------------------

    def on_select_changed(self, event: Select.Changed) -> None:
        self.kind = None if event.value in (Select.NULL, Select.BLANK) else str(event.value)
        self.rows = []
        self.redraw()
        self.load(self.kind)

    def on_input_changed(self, event: Input.Changed) -> None:
        self.redraw()

    def action_search(self) -> None:
        self.query_one("#events-search", Input).focus()

    def action_clear(self) -> None:
        self.query_one("#events-search", Input).value = ""
        self.query_one(DataTable).focus()

    def _search(self) -> str:
        return self.query_one("#events-search", Input).value.strip().lower()

    @staticmethod
    def _matches(e: s.Event, text: str) -> bool:
        return not text or text in f"{e.kind} {event_data_text(e.data)} layer {e.layer + 1}".lower()

    @staticmethod
    def _cells(e: s.Event) -> tuple:
        return (e.seq, f"{e.t_sim_s:.1f}", e.kind, e.layer + 1 if e.layer >= 0 else "-",
                e.gcode_line if e.gcode_line >= 0 else "-", event_data_text(e.data))

    def _count(self) -> None:
        table = self.query_one(DataTable)
        what = self.kind or "every kind"
        self.query_one("#events-count", Label).update(f" {table.row_count} of {len(self.rows)} events ({what})")
