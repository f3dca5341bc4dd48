"""A print's progress while ``job submit --follow`` waits for its end: layer, share done, volume, ETA.

It reads the station's state stream (published at least twice a second during a print) and shows the job's
figures on stderr (stdout keeps the command's result): a bar redrawn in place on a terminal, plain lines when
stderr is not one (a log, a pipe), one when the layer changes, at most every :data:`LINE_EVERY_S`, and the
last figures when the print ends. The ETA is the simulated time left over the pace the print has kept over
the last :data:`PACE_WINDOW_S` (the real-time factor until then; unknown at ``--rtf 0`` until measured).
"""
from __future__ import annotations

import collections
import contextlib
import queue
import sys
import threading
import time
from collections.abc import Iterator
from typing import TextIO

from fabric import schemas as s
from fabric.client import Client
from fabric.schemas.states import Station

__all__ = ["PrintProgress", "print_progress", "eta_text"]

LINE_EVERY_S = 2.0          # piped: a line at most this often (and at each new layer)
REDRAW_EVERY_S = 0.25       # on a terminal: the bar at most this often
PACE_WINDOW_S = 20.0        # the pace (simulated s per wall s) is measured over this long
BAR_WIDTH = 24


def eta_text(seconds: float | None) -> str:
    """``1:02:03``, ``4:05``; ``?`` when unknown."""
    if seconds is None or seconds != seconds or seconds < 0:
        return "?"
    total = int(round(seconds))
    h, rest = divmod(total, 3600)
    m, sec = divmod(rest, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class PrintProgress:
    """Renders the states of one job (``job_id``) to ``out``: a bar when ``tty``, else plain lines."""

    def __init__(self, job_id: str, out: TextIO, tty: bool) -> None:
        self.job_id, self.out, self.tty = job_id, out, tty
        self.last: s.StationState | None = None
        self._pace: collections.deque[tuple[float, float]] = collections.deque()
        self._shown_s = 0.0
        self._shown_layer = -2
        self._drawn = False

    def eta_s(self, st: s.StationState, now: float) -> float | None:
        """Wall seconds left: simulated time left over the measured pace (else the real-time factor)."""
        if st.state == Station.PAUSED:
            return None
        self._pace.append((now, st.t_sim_s))
        while len(self._pace) > 2 and now - self._pace[0][0] > PACE_WINDOW_S:
            self._pace.popleft()
        (w0, t0), (w1, t1) = self._pace[0], self._pace[-1]
        if w1 - w0 >= 1.0 and t1 > t0:
            return st.remaining_s / ((t1 - t0) / (w1 - w0))
        return st.remaining_s / st.rtf if st.rtf > 0 else None

    def text(self, st: s.StationState, eta: float | None) -> str:
        layers = f"layer {st.layer + 1}/{st.layers_total}" if st.layer >= 0 else f"layer -/{st.layers_total}"
        volume = f"{st.deposited_mm3:.0f}/{st.planned_mm3:.0f} mm3"
        tail = f"ETA {eta_text(eta)}" if st.state.printing else st.state
        return f"{layers}  {100 * st.progress_r:5.1f}%  {volume}  {tail}"

    def update(self, st: s.StationState, now: float | None = None) -> None:
        """Take a state of the station (states of other jobs are ignored) and show it when due."""
        if st.job_id != self.job_id:
            return
        now = time.monotonic() if now is None else now
        self.last = st
        eta = self.eta_s(st, now)
        if self.tty:
            if now - self._shown_s >= REDRAW_EVERY_S:
                filled = int(round(BAR_WIDTH * st.progress_r))
                bar = "#" * filled + "-" * (BAR_WIDTH - filled)
                self.out.write(f"\r  [{bar}] {self.text(st, eta)}\033[K")
                self.out.flush()
                self._shown_s, self._drawn = now, True
        elif (st.layer != self._shown_layer and now - self._shown_s >= LINE_EVERY_S) or self._shown_s == 0.0:
            self._line(st, eta, now)

    def _line(self, st: s.StationState, eta: float | None, now: float) -> None:
        self.out.write(f"  {self.text(st, eta)}\n")
        self.out.flush()
        self._shown_s, self._shown_layer = now, st.layer

    def close(self, final: s.StationState | None = None) -> None:
        """The last figures (``final``: the station's state once the print ended), and the line ended."""
        st = final if final is not None and final.job_id == self.job_id else self.last
        if st is None:
            return
        done = f"layer {max(st.layer, 0) + 1}/{st.layers_total}  {100 * st.progress_r:5.1f}%  " \
               f"{st.deposited_mm3:.0f}/{st.planned_mm3:.0f} mm3  " \
               f"{st.state if st.state.in_print else (st.reason or st.state)}"
        if self.tty:
            filled = int(round(BAR_WIDTH * st.progress_r))
            self.out.write(f"\r  [{'#' * filled}{'-' * (BAR_WIDTH - filled)}] {done}\033[K\n")
        else:
            self.out.write(f"  {done}\n")
        self.out.flush()


@contextlib.contextmanager
def print_progress(client: Client, job_id: str, quiet: bool = False, out: TextIO | None = None) -> Iterator[None]:
    """Show the progress of ``job_id``'s print while the body runs (nothing when ``quiet``)."""
    if quiet:
        yield
        return
    out = out or sys.stderr
    view = PrintProgress(job_id, out, tty=out.isatty())
    sub = client.subscribe("station", "state")
    stop = threading.Event()

    def run() -> None:
        while not stop.is_set():
            try:
                view.update(sub.get(timeout=0.2))
            except queue.Empty:
                continue
            except Exception:          # noqa: BLE001  a bad message must not end the command: skip it
                continue

    worker = threading.Thread(target=run, name="print-progress", daemon=True)
    worker.start()
    try:
        yield
    finally:
        stop.set()
        worker.join(timeout=1.0)
        sub.close()
        final = None
        with contextlib.suppress(Exception):
            final = client.state()
        view.close(final)
