"""The Files screen: the supervisor's library of every model and G-code file submitted (or added), most
recently used first, with what its last job did; print one again with that job's settings, or forget it."""
from __future__ import annotations

from typing import TYPE_CHECKING

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Header, Label

from fabric import schemas as s
from fabric.printjobs.library_text import date_text, plan_text, size_text
from fabric.tui.messages import CallRequested, Reply
from fabric.tui.screens.confirm import ConfirmDialog
from fabric.tui.screens.report import ReportDialog
from fabric.tui.widgets.reply_line import ReplyLine
from fabric.wire.errors import FabricError

if TYPE_CHECKING:
    from fabric.client import Client

PAGE = 200          # the most files listed (most recently used first)


def entry_report(e: s.LibraryFile) -> str:
    """Everything the library knows of one file, for its dialog."""
    settings = (f"profile {e.profile}, slicer {e.backend}, rtf {e.rtf:g}"
                + (f", filament {e.filament_diameter_mm:g} mm" if e.filament_diameter_mm else "")
                + "".join(f", {k}={v}" for k, v in sorted(e.overrides.items())))
    return "\n".join([f"{e.name} ({e.source}, {size_text(e.size_bytes)})",
                      f"file id    {e.file_id}",
                      f"added      {date_text(e.added_s)}",
                      f"last used  {date_text(e.used_s)} ({e.jobs} job{'s' if e.jobs != 1 else ''})",
                      f"last job   {e.last_job_id or '-'} {e.last_state}",
                      f"plan       {plan_text(e)}",
                      f"settings   {settings}" if e.source == "model" or e.jobs else "",
                      "",
                      "R prints it again with these settings (started once loaded and the plate is clear)"]).strip()


class FilesScreen(Screen):
    """Watches the console's client (the cell followed: its library is read again) and its jobs (a job's state
    shows here); asks the console to print a file again or forget it."""

    BINDINGS = [Binding("R", "print_again", "print again", show=False),
                Binding("delete,backspace", "remove", "remove", show=False),
                Binding("u", "refresh", "refresh", show=False)]

    def __init__(self) -> None:
        super().__init__()
        self.files: list[s.LibraryFile] = []
        self.client: Client | None = None

    def compose(self) -> ComposeResult:
        yield Header()
        with Vertical(id="files-body"):
            yield Label("library  R print again · del forget · u refresh · ⏎ details", classes="section-title")
            yield DataTable(id="files", cursor_type="row", zebra_stripes=True)
        yield ReplyLine(id="reply")
        yield Footer(compact=True)

    def on_mount(self) -> None:
        self.query_one(DataTable).add_columns("file", "name", "kind", "size", "jobs", "last job", "plan")
        self.watch(self.app, "reply", self.query_one(ReplyLine).show)
        self.watch(self.app, "jobs", self._on_jobs, init=False)      # a job's state shows here
        self.watch(self.app, "client", self._on_client)

    def _on_client(self, client: Client | None) -> None:
        self.client = client
        self.action_refresh()

    def _on_jobs(self, _: list) -> None:
        self.action_refresh()

    def on_screen_resume(self) -> None:
        self.action_refresh()

    @work(thread=True, exclusive=True, group="files")
    def action_refresh(self) -> None:
        client = self.client
        if client is None:
            return
        try:
            page = client.files(0, PAGE)
        except FabricError as err:
            self.post_message(Reply("files", False, f"[{err.code}] {err.message}"))
            return
        self.app.call_from_thread(self.show_files, page)

    def show_files(self, page: s.FileList) -> None:
        table = self.query_one(DataTable)
        keep = self._selected()
        self.files = list(page.files)
        table.clear()
        for e in self.files:
            last = f"{e.last_state or '-'}"
            table.add_row(e.file_id, e.name, e.source, size_text(e.size_bytes), str(e.jobs), last, plan_text(e),
                          key=e.file_id)
        if keep is not None and keep in table.rows:
            table.move_cursor(row=table.get_row_index(keep))
        table.border_title = f"{page.total} file{'s' if page.total != 1 else ''}"

    def _selected(self) -> str | None:
        table = self.query_one(DataTable)
        if table.row_count == 0:
            return None
        return table.coordinate_to_cell_key(table.cursor_coordinate).row_key.value

    def _entry(self) -> s.LibraryFile | None:
        key = self._selected()
        return next((e for e in self.files if e.file_id == key), None)

    def action_print_again(self) -> None:
        e = self._entry()
        if e is None:
            self.post_message(Reply("print again", False, "the library is empty: submit a file first (a)"))
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.post_message(CallRequested("print again", lambda c: self._print(c, e), refresh_jobs=True))
        self.app.push_screen(ConfirmDialog("Print again", f"Queue {e.name} again ({e.profile}, rtf {e.rtf:g}), "
                                                          f"started once loaded and the plate is clear?"), confirmed)

    def _print(self, client: Client, e: s.LibraryFile) -> s.Ack:
        """(A worker thread) A new job from the library file, with its last job's settings."""
        acc = client.submit(s.JobSubmit(model=b"", filename="", file_id=e.file_id, profile=e.profile,
                                        backend=e.backend, overrides=dict(e.overrides) if e.source == "model" else {},
                                        start=True, rtf=e.rtf, filament_diameter_mm=e.filament_diameter_mm,
                                        layers=e.layer_mode if e.source == "model" else "planar"))
        return s.Ack(ok=True, message=f"job {acc.job_id} queued: {e.name} again (from the library)")

    def action_remove(self) -> None:
        e = self._entry()
        if e is None:
            return

        def confirmed(yes: bool | None) -> None:
            if yes:
                self.post_message(CallRequested("file remove", lambda c: self._remove(c, e)))
        self.app.push_screen(ConfirmDialog("Forget file", f"Remove {e.name} ({e.file_id}) from the library? Its "
                                                          f"jobs' records stay."), confirmed)

    def _remove(self, client: Client, e: s.LibraryFile) -> s.Ack:
        """(A worker thread) Forget the file; the list is read again after."""
        ack = client.file_remove(e.file_id)
        self.app.call_from_thread(self.action_refresh)
        return ack

    def on_data_table_row_selected(self, event: DataTable.RowSelected) -> None:
        e = next((x for x in self.files if x.file_id == event.row_key.value), None)
        if e is not None:
            self.app.push_screen(ReportDialog(f"File {e.file_id}", entry_report(e)))
