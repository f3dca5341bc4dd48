"""A print as it goes: ``job submit --follow`` shows layer, share, volume and ETA; ``job list`` shows the job's
live figures (the supervisor writes the station's onto the record, at most every 2 s, as a writer step);
``fabric-cli up`` ends with a last line saying how the cell stopped."""
from __future__ import annotations

import io
import json
import queue
import re
import signal
import subprocess
import sys
import threading
import time
import uuid

import pytest

from fabric import schemas as s
from fabric.cli.progress import PrintProgress, eta_text
from fabric.demo import sample_model
from fabric.printjobs.history import material_text, state_text
from fabric.printjobs.live import apply_live

from support.loopback import free_port


def _printing(job_id: str = "j1") -> s.JobRecord:
    rec = s.JobRecord(job_id=job_id, filename="p.stl", state="printing", layer=2, started_s=100.0)
    rec.segments.append(s.JobSegment(began="start", started_s=100.0, t_sim_start_s=10.0, last_layer=2))
    return rec


def _state(job_id: str = "j1", **kw) -> s.StationState:
    base = dict(state="printing", job_id=job_id, t_sim_s=70.0, progress_r=0.25, deposited_mm3=500.0,
                planned_mm3=2000.0, layer=5, layers_total=20, remaining_s=180.0, rtf=2.0)
    return s.StationState(**{**base, **kw})


# --- the record's live figures ------------------------------------------------------------------------------

def test_the_record_takes_the_stations_figures_while_it_prints() -> None:
    rec = _printing()
    assert apply_live(rec, _state(), wall_s=130.0)
    assert (rec.progress_r, rec.deposited_mm3, rec.layer, rec.sim_elapsed_s, rec.wall_elapsed_s) == (
        0.25, 500.0, 5, 60.0, 30.0)
    assert rec.stage == "printing layer 6" and rec.segments[-1].last_layer == 5
    assert rec.segments[-1].deposited_mm3 == 500.0                  # the running run's share follows
    assert not apply_live(rec, _state(), wall_s=130.0)              # nothing new: no save


def test_the_material_line_says_when_the_filament_is_counted() -> None:
    """The volume follows the print; the filament is the station's count at a run's end: a run still open does
    not show "0 mm of filament"."""
    rec = _printing()
    apply_live(rec, _state(), wall_s=130.0)
    assert material_text(rec) == "500 mm3 deposited, filament counted when the run ends"
    rec.segments[-1].ended, rec.filament_mm = "stopped", 166.0
    assert material_text(rec) == "500 mm3 deposited, 166 mm of filament"
    rec.segments.append(s.JobSegment(began="restart", started_s=200.0, t_sim_start_s=80.0, from_layer=5))
    rec.deposited_mm3 = 900.0
    assert material_text(rec) == "900 mm3 deposited, 166 mm of filament by the end of run 1 (run 2 still open)"


def test_prepared_is_said_of_a_queued_job_only() -> None:
    """"prepared" tells a queued job was sliced, planned and checked ahead; on the station or ended it is noise
    (``job show`` said "printing (prepared)")."""
    rec = _printing()
    rec.prepared = True
    assert state_text(rec) == "printing"
    rec.state = "queued"
    assert state_text(rec) == "queued (prepared)"
    rec.prepared = False
    assert state_text(rec) == "queued"


@pytest.mark.parametrize("why, rec_state, st", [
    ("another job", "printing", _state(job_id="other")),
    ("the job ended meanwhile", "finished", _state()),
    ("the station no longer prints", "printing", _state(state="paused")),
    ("a state from before this run", "printing", _state(t_sim_s=5.0)),
])
def test_the_events_keep_the_last_word(why, rec_state, st) -> None:
    rec = _printing()
    rec.state = rec_state
    assert not apply_live(rec, st, wall_s=130.0), why
    assert rec.deposited_mm3 == 0.0


# --- what --follow shows --------------------------------------------------------------------------------------

def test_piped_progress_is_plain_lines_with_layer_share_volume_and_eta() -> None:
    out = io.StringIO()
    view = PrintProgress("j1", out, tty=False)
    view.update(_state(layer=-1, progress_r=0.0, deposited_mm3=0.0), now=1.0)
    view.update(_state(layer=0, progress_r=0.01, t_sim_s=72.0), now=2.0)           # < 2 s: not yet
    view.update(_state(job_id="other", layer=9), now=9.0)                            # another job: ignored
    view.update(_state(layer=1, progress_r=0.10, deposited_mm3=200.0, t_sim_s=80.0), now=4.0)
    view.update(_state(layer=1, progress_r=0.12, t_sim_s=84.0), now=7.0)            # same layer: no line
    view.close(_state(state="idle", reason="finished", layer=19, progress_r=1.0, deposited_mm3=2000.0))
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue() and len(lines) == 3, lines
    assert re.fullmatch(r"  layer -/20 +0\.0%  0/2000 mm3  ETA 1:30", lines[0]), lines[0]   # 180 s at rtf 2
    assert re.fullmatch(r"  layer 2/20 +10\.0%  200/2000 mm3  ETA 0:\d\d", lines[1]), lines[1]  # measured pace
    assert lines[2] == "  layer 20/20  100.0%  2000/2000 mm3  finished"


def test_on_a_terminal_it_is_one_bar_redrawn_in_place() -> None:
    out = io.StringIO()
    view = PrintProgress("j1", out, tty=True)
    view.update(_state(progress_r=0.5), now=1.0)
    view.update(_state(progress_r=0.75, state="paused"), now=2.0)
    view.close()
    text = out.getvalue()
    assert text.count("\r") == 3 and text.endswith("\n") and text.count("\n") == 1
    assert "[############------------] layer 6/20   50.0%  500/2000 mm3  ETA" in text
    assert "paused" in text.split("\r")[2]


def test_eta_text() -> None:
    assert [eta_text(x) for x in (None, -1.0, 59.4, 61.0, 3725.0)] == ["?", "?", "0:59", "1:01", "1:02:05"]


# --- a cell: follow, job list, up's last line -----------------------------------------------------------------

def _lines(proc: subprocess.Popen) -> queue.Queue:
    q: queue.Queue = queue.Queue()

    def pump() -> None:
        for line in proc.stdout:
            q.put(line.rstrip("\n"))
        q.put(None)
    threading.Thread(target=pump, daemon=True).start()
    return q


@pytest.mark.timeout(240)
def test_a_print_shows_its_progress_and_up_says_how_it_stopped(tmp_path) -> None:
    cell, hub = f"p{uuid.uuid4().hex[:8]}", f"tcp/127.0.0.1:{free_port()}"
    fabric = [sys.executable, "-m", "fabric.cli.main"]
    up = subprocess.Popen([*fabric, "up", "--listen", hub, "--cell", cell, "--data-dir", str(tmp_path)],
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    said = _lines(up)
    try:
        seen: list[str] = []
        while not any(" up in " in x for x in seen):
            line = said.get(timeout=120)
            assert line is not None, "\n".join(seen)
            seen.append(line)
        at = ["--connect", hub, "--cell", cell]
        follow = subprocess.Popen([*fabric, "job", "submit", str(sample_model()), "--profile", "robot-1.2mm",
                                   "--start", "--rtf", "100", "--follow", *at], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        live = []
        while follow.poll() is None:
            done = subprocess.run([*fabric, "job", "list", *at, "--json"], capture_output=True, text=True,
                                  timeout=60)
            jobs = json.loads(done.stdout)["jobs"] if done.returncode == 0 else []
            if jobs and jobs[0]["state"] == "printing":
                live.append(jobs[0])
            time.sleep(0.5)
        out, err = follow.communicate(timeout=60)
        assert follow.returncode == 0, out + err
        # job list, during the print: the figures move (not sim s 0.0 and mm3 0 until the end)
        moving = [(j["sim_elapsed_s"], j["deposited_mm3"], j["progress_r"]) for j in live if j["deposited_mm3"] > 0]
        assert len(set(moving)) >= 2, live
        for i in range(3):
            assert [m[i] for m in moving] == sorted(m[i] for m in moving), moving
        assert all(0 < p < 1 and t > 0 for t, _, p in moving), moving
        # --follow, piped: lines with the layer, the share, the volume and the ETA, then the end
        progress = [ln for ln in err.splitlines() if ln.startswith("  layer ")]
        assert len(progress) >= 4, err
        assert all(re.search(r"layer (\d+|-)/33 +[\d.]+%  \d+/\d+ mm3  ETA [\d:?]+$", ln) for ln in progress[:-1]), err
        layers = [int(m.group(1)) for ln in progress if (m := re.match(r"  layer (\d+)/", ln))]
        assert layers == sorted(layers) and layers[-1] == 33, err
        assert "100.0%" in progress[-1] and progress[-1].endswith("  finished"), progress[-1]
        assert "\r" not in err
        assert "finished" in out.splitlines()[0]
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(timeout=60)
    rest = []
    while (line := said.get(timeout=10)) is not None:
        rest.append(line)
    assert "stopping services ..." in rest and rest[-1] == f"cell '{cell}' stopped: 5 services ended; hub closed", rest
    assert up.returncode == 0
