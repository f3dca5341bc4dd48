"""The Jobs screen: the queue (reorder, remove, start next) and the history with outcome, duration, material and
every run of each print; print a job again from either."""
from __future__ import annotations

from typing import TYPE_CHECKING

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Header, Label

from fabric import schemas as s
from fabric.printjobs.queue import WAITING_STATES
from fabric.tui.format import duration_text, job_report
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.widgets.reply_line import ReplyLine

if TYPE_CHECKING:
    from textual import getters

    from fabric.tui.app import FabricConsole


class JobsScreen(Screen):
    # listed on the screen itself (the footer keeps the console's keys, the same on every screen)
    BINDINGS = [Binding("n", "next", "next job", show=False),
                Binding("delete,backspace", "remove", "remove", show=False),
                Binding("left_square_bracket", "move(-1)", "up", show=False),
                Binding("right_square_bracket", "move(1)", "down", show=False),
                Binding("R", "reprint", "print again", show=False)]

    if TYPE_CHECKING:
        app = getters.app(FabricConsole)      # self.app is the console (for the type checker)

    def compose(self) -> ComposeResult:
        yield Header()
        with Vertical(id="jobs-body"):
            yield Label("queue  a submit · n next · [ ] move · del remove · R print again · ⏎ record",
                        classes="section-title")
            yield DataTable(id="queue", cursor_type="row", zebra_stripes=True)
            yield Label("history", classes="section-title")
            yield DataTable(id="history", cursor_type="row", zebra_stripes=True)
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one("#queue", DataTable).add_columns("job", "state", "file", "stage / waiting for")
        self.query_one("#history", DataTable).add_columns("job", "outcome", "file", "runs", "material",
                                                          "sim / wall", "ended", "reason")
        self.watch(self.app, "jobs", self._on_jobs)
        self.watch(self.app, "reply", self.query_one(ReplyLine).show)

    # --- attributes down -------------------------------------------------------------

    def _on_jobs(self, jobs: list[s.JobRecord]) -> None:
        queue_t, history_t = self.query_one("#queue", DataTable), self.query_one("#history", DataTable)
        keep_q, keep_h = self._selected("#queue"), self._selected("#history")
        queue_t.clear()
        history_t.clear()
        for rec in jobs:                         # whole ids: what fabric-cli job show takes
            if rec.state in s.FINAL_JOB_STATES:
                continue
            waiting = rec.waiting_for and f"waiting for the {rec.waiting_for}"
            queue_t.add_row(rec.job_id, rec.state, rec.filename, waiting or rec.stage or rec.reason, key=rec.job_id)
        done = sorted((r for r in jobs if r.state in s.FINAL_JOB_STATES), key=lambda r: -r.ended_s)
        for rec in done:
            took = (f"{duration_text(rec.sim_elapsed_s)}/{duration_text(rec.wall_elapsed_s)}"
                    if rec.started_s else "-")
            material = f"{rec.deposited_mm3:.0f} mm3" if rec.started_s else "-"
            outcome = {"finished": "[green]finished[/]", "failed": "[red]failed[/]"}.get(rec.state, rec.state)
            runs = str(len(rec.segments)) if rec.segments else "-"
            history_t.add_row(rec.job_id, outcome, rec.filename, runs, material, took,
                              self.app.time_text(rec.ended_s), rec.reason, key=rec.job_id)
        for table, key in ((queue_t, keep_q), (history_t, keep_h)):
            if key is not None and key in table.rows:
                table.move_cursor(row=table.get_row_index(key))

    def _selected(self, table_id: str) -> str | None:
        table = self.query_one(table_id, DataTable)
        if table.row_count == 0:
            return None
        return table.coordinate_to_cell_key(table.cursor_coordinate).row_key.value

    def _focused_record(self) -> s.JobRecord | None:
        table_id = "#history" if self.query_one("#history", DataTable).has_focus else "#queue"
        return self._record(self._selected(table_id))

    def _record(self, job_id: str | None) -> s.JobRecord | None:
        return next((r for r in self.app.jobs if r.job_id == job_id), None)

    # --- actions ---------------------------------------------------------------------

    def action_next(self) -> None:
        """The plate is clear: the next job is loaded (and started if it was submitted to start). Asked first:
        it is the operator's word that nothing is left on the plate."""
        st = self.app.station_state
        on_plate = ""
        if st is not None and not st.plate_clear:
            on_plate = f" (it holds the part of job {st.plate_job_id or '?'}, {st.plate_mm3:.0f} mm3)"
        head = next((r for r in self.app.jobs if r.state in WAITING_STATES), None)
        then = (f"Then job {head.job_id} ({head.filename}) is loaded" + (" and started." if head.start else ".")
                if head is not None else "No job is waiting: the next one submitted to start starts at once.")

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.app.run_call("job next", lambda c: c.job_next(), refresh_jobs=True)
        self.app.push_screen(ConfirmDialog("Next job", f"Is the plate clear{on_plate}? {then}"), confirmed)

    def action_remove(self) -> None:
        rec = self._focused_record()
        if rec is None:
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.app.run_call("job remove", lambda c: self._remove(c, rec.job_id), refresh_jobs=True)
        self.app.push_screen(ConfirmDialog("Remove job", f"Remove job {rec.job_id} ({rec.filename})?"), confirmed)

    def _remove(self, client, job_id: str) -> s.Ack:
        """(A worker thread) Remove the job; it leaves the screen at once, not when the list is next read."""
        ack = client.job_remove(job_id)
        self.app.call_from_thread(self.app.forget_job, job_id)
        return ack

    def action_move(self, delta: int) -> None:
        rec = self._record(self._selected("#queue"))
        waiting = [r.job_id for r in self.app.jobs if r.state in WAITING_STATES]
        if rec is None or rec.job_id not in waiting:
            self.app.show_reply("job move", False, "only a waiting job (queued, slicing, planning, checking) moves")
            return
        position = max(0, min(len(waiting) - 1, waiting.index(rec.job_id) + delta))
        self.app.run_call("job move", lambda c: c.job_move(rec.job_id, position), refresh_jobs=True)

    def action_reprint(self) -> None:
        rec = self._focused_record()
        if rec is not None:
            self.app.reprint(rec)

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        rec = self._record(event.row_key.value)
        if rec is not None:
            self.app.push_screen(ReportDialog(f"Job {rec.job_id}", job_report(rec)))
