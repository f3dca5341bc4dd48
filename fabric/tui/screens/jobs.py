"""The Jobs screen: the queue (reorder, remove, start next), what is on the plate, and the history with outcome,
duration, material and every run of each print; print a job again from either."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rich.text import Text
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Header, Label, Static

from fabric import schemas as s
from fabric.schemas import states
from fabric.tui.format import clock_text, duration_text, job_report, plate_text
from fabric.tui.messages import CallRequested, JobRemoved, Reply, ReprintRequested
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.widgets.reply_line import ReplyLine

if TYPE_CHECKING:
    from fabric.client import Client

# how an ended job's outcome reads in the history (its state as it is else)
OUTCOME_MARKUP = {states.PrintJob.FINISHED: "[green]finished[/]", states.PrintJob.FAILED: "[red]failed[/]"}


class JobsScreen(Screen):
    """Watches the console's jobs and station state; asks the console (messages) to run the job commands."""

    # listed on the screen itself (the footer keeps the console's keys, the same on every screen)
    BINDINGS = [Binding("n", "next", "next job", show=False),
                Binding("delete,backspace", "remove", "remove", show=False),
                Binding("left_square_bracket", "move(-1)", "up", show=False),
                Binding("right_square_bracket", "move(1)", "down", show=False),
                Binding("R", "reprint", "print again", show=False)]

    def __init__(self) -> None:
        super().__init__()
        self.jobs: list[s.JobRecord] = []
        self.station_state: Any = None
        self._plate_shown: str | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        with Vertical(id="jobs-body"):
            yield Label("queue  a submit · n next · [ ] move · del remove · R print again · ⏎ record",
                        classes="section-title")
            yield DataTable(id="queue", cursor_type="row", zebra_stripes=True)
            yield Static(id="plate")
            yield Label("history", classes="section-title")
            yield DataTable(id="history", cursor_type="row", zebra_stripes=True)
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one("#queue", DataTable).add_columns("job", "state", "file", "stage / waiting for")
        self.query_one("#history", DataTable).add_columns("job", "outcome", "file", "runs", "material",
                                                          "sim / wall", "ended", "reason")
        self.watch(self.app, "jobs", self._on_jobs)
        self.watch(self.app, "station_state", self._on_state)
        self.watch(self.app, "reply", self.query_one(ReplyLine).show)

    # --- attributes down -------------------------------------------------------------

    def _on_state(self, st: Any) -> None:
        self.station_state = st             # what the next job's question says is on the plate
        occupied = st is not None and not st.plate_clear
        text = plate_text(st) + (": once it is off, n loads the next job" if occupied else "")
        if text != self._plate_shown:       # the state comes twice a second: the line is drawn when it changes
            self._plate_shown = text
            self.query_one("#plate", Static).update(Text(text or "plate: no word from the station yet",
                                                         style="yellow" if occupied else ""))

    def _on_jobs(self, jobs: list[s.JobRecord]) -> None:
        self.jobs = list(jobs)
        queue_t, history_t = self.query_one("#queue", DataTable), self.query_one("#history", DataTable)
        keep_q, keep_h = self._selected("#queue"), self._selected("#history")
        rows_q, rows_h = queue_t.cursor_row, history_t.cursor_row
        queue_t.clear()
        history_t.clear()
        for rec in jobs:                         # whole ids: what fabric-cli job show takes
            if states.PrintJob(rec.state).ended:
                continue
            waiting = rec.waiting_for and f"waiting for the {rec.waiting_for}"
            queue_t.add_row(rec.job_id, rec.state, rec.filename, waiting or rec.stage or rec.reason, key=rec.job_id)
        done = sorted((r for r in jobs if states.PrintJob(r.state).ended), key=lambda r: -r.ended_s)
        for rec in done:
            took = (f"{duration_text(rec.sim_elapsed_s)}/{duration_text(rec.wall_elapsed_s)}"
                    if rec.started_s else "-")
            material = f"{rec.deposited_mm3:.0f} mm3" if rec.started_s else "-"
            outcome = OUTCOME_MARKUP.get(states.PrintJob(rec.state), rec.state)
            runs = str(len(rec.segments)) if rec.segments else "-"
            history_t.add_row(rec.job_id, outcome, rec.filename, runs, material, took,
                              clock_text(rec.ended_s), rec.reason, key=rec.job_id)
        for table, key, row in ((queue_t, keep_q, rows_q), (history_t, keep_h, rows_h)):
            if key is not None and key in table.rows:
                table.move_cursor(row=table.get_row_index(key))
            elif table.row_count:             # the job selected is gone (removed, ended): the row where it was
                table.move_cursor(row=min(row, table.row_count - 1))

    def _selected(self, table_id: str) -> str | None:
        table = self.query_one(table_id, DataTable)
        if table.row_count == 0:
            return None
        return table.coordinate_to_cell_key(table.cursor_coordinate).row_key.value

    def _focused_record(self) -> s.JobRecord | None:
        table_id = "#history" if self.query_one("#history", DataTable).has_focus else "#queue"
        return self._record(self._selected(table_id))

    def _record(self, job_id: str | None) -> s.JobRecord | None:
        return next((r for r in self.jobs if r.job_id == job_id), None)

    def _waiting(self) -> list[s.JobRecord]:
        """The jobs in the queue, being prepared or waiting to be, in queue order (the ones that move)."""
        return [r for r in self.jobs if states.PrintJob(r.state).waiting]

    # --- actions: messages up ----------------------------------------------------------

    def action_next(self) -> None:
        """The plate is clear: the next job is loaded (and started if it was submitted to start). Asked first:
        it is the operator's word that nothing is left on the plate."""
        st = self.station_state
        on_plate = ""
        if st is not None and not st.plate_clear:
            on_plate = f" (it holds the part of job {st.plate_job_id or '?'}, {st.plate_mm3:.0f} mm3)"
        head = next(iter(self._waiting()), None)
        then = (f"Then job {head.job_id} ({head.filename}) is loaded" + (" and started." if head.start else ".")
                if head is not None else "No job is waiting: the next one submitted to start starts at once.")

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.post_message(CallRequested("job next", lambda c: c.job_next(), refresh_jobs=True))
        self.app.push_screen(ConfirmDialog("Next job", f"Is the plate clear{on_plate}? {then}"), confirmed)

    def action_remove(self) -> None:
        rec = self._focused_record()
        if rec is None:
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.post_message(CallRequested("job remove", lambda c: self._remove(c, rec.job_id),
                                                refresh_jobs=True))
        self.app.push_screen(ConfirmDialog("Remove job", f"Remove job {rec.job_id} ({rec.filename})?"), confirmed)

    def _remove(self, client: Client, job_id: str) -> s.Ack:
        """(A worker thread) Remove the job; it leaves the screen at once, not when the list is next read."""
        ack = client.job_remove(job_id)
        self.post_message(JobRemoved(job_id))
        return ack

    def action_move(self, delta: int) -> None:
        rec = self._record(self._selected("#queue"))
        waiting = [r.job_id for r in self._waiting()]
        if rec is None or rec.job_id not in waiting:
            why = "only a waiting job (queued, slicing, planning, checking) moves"
            self.post_message(Reply("job move", False, why))
            return
        position = max(0, min(len(waiting) - 1, waiting.index(rec.job_id) + delta))
        self.post_message(CallRequested("job move", lambda c: c.job_move(rec.job_id, position), refresh_jobs=True))

    def action_reprint(self) -> None:
        rec = self._focused_record()
        if rec is not None:
            self.post_message(ReprintRequested(rec))

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        rec = self._record(event.row_key.value)
        if rec is not None:
            self.app.push_screen(ReportDialog(f"Job {rec.job_id}", job_report(rec)))
