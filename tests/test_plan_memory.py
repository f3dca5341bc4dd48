"""Planning in bounded memory (issue 17, memory): the toolpath in chunks, the program in files mapped back and read
through with its pages given back, the cycle time in blocks, one plan kept by the service, clients without a
shared-memory pool. Every chunked or blocked result is checked against the whole one."""
from __future__ import annotations

import errno
import io
import itertools
import json
import sys
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fabric.cli.main import main
from fabric.gcode import ToolpathChunks, parse_gcode
from fabric.motion.program import COLUMNS, column_spec
from fabric.motion.program_file import FileSink
from fabric.motion.timing import StartState, program_times, time_program
from fabric.planning import PlanOptions, plan_gcode
from fabric.planning.post.files import write_export
from fabric.programs import program_artifact, program_artifact_pieces
from fabric.robot.cell import Cell
from fabric.services.planner import PlannerService
from fabric.wire import codec
from fabric.wire.config import SessionSettings, zenoh_config


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.builtin("irb140")


def rich_gcode(n_layers: int = 30, seed: int = 1, markers: bool = True) -> str:
    """Layers of moves with travels, retractions, fan, dwells, set points, arcs, relative moves and G92."""
    rng = np.random.default_rng(seed)
    out = ["M140 S60", "M104 S200", "G28", "G90", "M82", "G92 E0", "M190 S60", "M109 S200"]
    e = 0.0
    for layer in range(n_layers):
        z = 0.2 * (layer + 1)
        if markers:
            out += [";LAYER_CHANGE", f";Z:{z:.2f}", ";TYPE:Perimeter"]
        out.append(f"G1 Z{z:.3f} F600")
        for _ in range(int(rng.integers(20, 200))):
            r = rng.random()
            x, y = rng.uniform(20, 200, 2)
            if r < 0.7:
                e += rng.uniform(0.01, 0.2)
                out.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.5f} F{60 * rng.integers(10, 66)}")
            elif r < 0.8:
                out.append(f"G0 X{x:.3f} Y{y:.3f} F9000")
            elif r < 0.85:
                out += [f"G1 E{e - 0.8:.5f} F2400", f"G1 X{x:.3f} Y{y:.3f}", f"G1 E{e:.5f}"]
            elif r < 0.88:
                out.append(f"M106 S{rng.integers(0, 255)}")
            elif r < 0.9:
                out.append(f"G4 P{rng.integers(1, 500)}")
            elif r < 0.92:
                out.append(f"M104 S{rng.integers(190, 220)}")
            elif r < 0.95:
                radius = rng.uniform(3, 8)
                out += ["G91", f"G2 X{2 * radius:.3f} Y0 I{radius:.3f} J0 E0.3", "G90"]
            else:
                out.append("G92 E0")
                e = 0.0
    out += ["M104 S0", "M140 S0"]
    return "\n".join(out) + "\n"


# -- the toolpath in chunks --------------------------------------------------------------------------------

@pytest.mark.parametrize("markers", [True, False])
@pytest.mark.parametrize("rows", [50, 700])
def test_the_chunks_are_the_whole_toolpath(markers: bool, rows: int) -> None:
    text = rich_gcode(seed=3, markers=markers)
    whole = parse_gcode(text, block_bytes=1024)
    chunks = ToolpathChunks(text, chunk_rows=rows, block_bytes=1024)
    parts = list(chunks)
    assert len(parts) > 3 and [last for _, last in parts] == [False] * (len(parts) - 1) + [True]
    for name in ("xyz_mm", "e_mm", "feed_mm_s", "line", "layer", "feature", "event_kind", "event_value",
                 "event_aux", "event_line"):
        assert np.array_equal(np.concatenate([getattr(t, name) for t, _ in parts]), getattr(whole, name)), name
    first_row = np.cumsum([0] + [len(t) for t, _ in parts[:-1]])
    rows_of_events = np.concatenate([t.event_row + k for (t, _), k in zip(parts, first_row, strict=True)])
    assert np.array_equal(rows_of_events, whole.event_row)
    assert np.array_equal(np.concatenate([t.starts_mm() for t, _ in parts]), whole.starts_mm())
    summary = chunks.summary
    assert summary is not None and (summary.n_lines, summary.n_rows) == (whole.n_lines, len(whole))
    assert np.array_equal(summary.layer_z_mm, whole.layer_z_mm, equal_nan=True) and summary.n_layers > 20
    assert summary.unknown_commands == whole.unknown_commands
    # every cut lies between two extruding moves with nothing in between
    for (t, _), (nxt, _) in itertools.pairwise(parts):
        assert t.e_mm[-1] > 0 and nxt.e_mm[0] > 0 and not (nxt.event_row == 0).any()


# -- the program in chunks, in memory or in files --------------------------------------------------------

@pytest.mark.slow                         # 2.5 s each (not the fast tier)
@pytest.mark.parametrize("markers", [True, False])
def test_planning_in_chunks_gives_the_whole_plan(cell: Cell, tmp_path: Path, markers: bool) -> None:
    text = rich_gcode(n_layers=40, seed=4, markers=markers)
    one = plan_gcode(text, cell, PlanOptions(ik_block_rows=1_000_000))
    many = plan_gcode(text, cell, PlanOptions(ik_block_rows=1000))
    mapped = plan_gcode(text, cell, PlanOptions(ik_block_rows=1000), program_dir=tmp_path / "plan")
    assert len(one.program) > 8000
    for name in COLUMNS:
        a, b, c = (getattr(r.program, name) for r in (one, many, mapped))
        if name in ("q_rad", "quat_wxyz"):            # IK blocks start elsewhere: the same joints to 1e-9
            assert np.allclose(a, b, atol=1e-9), name
        else:
            assert np.array_equal(a, b), name
        assert np.array_equal(b, c), name
    assert not mapped.program.q_rad.flags.writeable and mapped.program.pager is not None
    metas = [dict(r.program.meta, options={**r.program.meta["options"], "ik_block_rows": 0}) for r in (one, many)]
    assert metas[0] == metas[1] and mapped.program.meta == many.program.meta
    for r in (many, mapped):
        assert np.array_equal(r.report.status, one.report.status) and r.report.counts == one.report.counts
        assert r.report.feasible_r == one.report.feasible_r and r.report.first_unreachable is None
        for k in ("moves", "rows", "targets", "layers", "travel_lifts", "fan_events_dropped", "gcode_lines"):
            assert getattr(r.stats, k) == getattr(one.stats, k), k
        for k in ("extruded_volume_mm3", "path_length_mm", "print_length_mm"):
            assert getattr(r.stats, k) == pytest.approx(getattr(one.stats, k), rel=1e-12), k
        assert r.estimate_s == pytest.approx(one.estimate_s, rel=1e-12)
        assert np.allclose(r.t_end_s, one.t_end_s, rtol=1e-12, atol=1e-9)
    # the same program, the same artifact (id and bytes), whether it lives in memory or in files
    art = program_artifact(many.program, name="r.program")
    aid, pieces = program_artifact_pieces(mapped.program, name="r.program")
    assert aid == art.artifact_id and b"".join(pieces) == codec.encode(art) == b"".join(list(iter(pieces)))
    # exports of the mapped program are the in-memory one's, byte for byte
    for fmt in ("csv", "rapid", "krl", "urscript"):
        texts = []
        for r in (many, mapped):
            buf = io.StringIO()
            write_export(r.program, fmt, buf, cell, module_targets=700, t_end_s=r.t_end_s)
            texts.append(buf.getvalue())
        assert texts[0] == texts[1], fmt


def test_the_times_come_block_by_block_and_stay(cell: Cell, tmp_path: Path) -> None:
    """on_times tells how many rows are timed as the cycle time is computed; those rows do not change after
    (a CSV export streams behind the computation)."""
    seen: list[tuple[int, np.ndarray]] = []
    res = plan_gcode(rich_gcode(n_layers=20, seed=5), cell, PlanOptions(ik_block_rows=1000),
                     program_dir=tmp_path / "plan", on_times=lambda t, rows: seen.append((rows, t[:rows].copy())))
    rows = [r for r, _ in seen]
    assert rows[0] == 0 and rows[-1] == len(res.program) and rows == sorted(rows) and len(rows) > 4
    for r, early in seen:
        assert np.array_equal(early, res.t_end_s[:r])


def test_a_failed_plan_leaves_no_files(cell: Cell, tmp_path: Path) -> None:
    text = rich_gcode(n_layers=6, seed=2) + "G1 X10 Y10 X20\n"          # a letter twice: an error at the end
    with pytest.raises(Exception, match="appears twice"):
        plan_gcode(text, cell, PlanOptions(ik_block_rows=1000), program_dir=tmp_path / "plan")
    assert not (tmp_path / "plan").exists()


def test_the_cycle_time_in_blocks_is_the_whole_programs(cell: Cell) -> None:
    """Short segments at high speed and no stop: the look-ahead reaches far, the windows must too."""
    rng = np.random.default_rng(3)
    n = 12_000
    heading = np.cumsum(rng.uniform(-0.3, 0.3, n))
    step = rng.choice([0.05, 0.2, 1.0, 3.0], size=n, p=[0.4, 0.3, 0.2, 0.1])
    xy = np.clip(125 + np.cumsum(np.stack([np.cos(heading) * step, np.sin(heading) * step], 1), 0), 10, 240)
    feed = rng.choice([1800, 6000, 18000], size=n)
    text = "M83\nG1 Z0.3 F3000\n" + "".join(f"G1 X{x:.3f} Y{y:.3f} E0.01 F{f}\n" for (x, y), f in zip(xy, feed,
                                                                                                      strict=True))
    prog = plan_gcode(text, cell, PlanOptions(max_tcp_speed_mm_s=300.0)).program
    start = StartState.at_joints(cell.robot, prog.wobj, cell.home_q_rad)
    whole = time_program(prog, cell.robot, 1.0, start_state=start)
    for block in (300, 2048):
        blocked = program_times(prog, cell.robot, 1.0, start, block_rows=block)
        assert np.abs(blocked.t_end_s - whole.t_end_s).max() < 1e-9
        assert blocked.total_s == pytest.approx(whole.total_s, rel=1e-13)
        assert np.array_equal(blocked.slowed_rows, whole.slowed_rows)


# -- memory -----------------------------------------------------------------------------------------------

def _raster(n_moves: int) -> str:
    """A serpentine raster of 5 mm infill segments, layer markers and a retraction per layer."""
    xs = np.linspace(30.0, 220.0, 39)[1:]
    lines = ["M83", "G1 Z5 F3000"]
    moves, k = 0, 0
    while moves < n_moves:
        z = 0.2 * (k + 1)
        lines += [";LAYER_CHANGE", f";Z:{z:.2f}", "G1 E-0.8 F2400", f"G1 Z{z:.3f} F6000", "G1 X30 Y30", "G1 E0.8"]
        for i in range(100):
            row = xs if i % 2 == 0 else xs[::-1]
            lines += [f"G1 X{x:.3f} Y{30 + 0.45 * i:.3f} E0.166" for x in row]
            moves += len(row)
        k += 1
    return "\n".join(lines) + "\n"


@pytest.mark.slow                         # 3.6 s (not the fast tier)
def test_planning_holds_a_chunk_not_the_file(cell: Cell, tmp_path: Path) -> None:
    """Planned into files in chunks of 20 k rows, three times the moves take the same memory: the planner's
    own allocations (tracemalloc sees NumPy's) are a chunk's and the blocks', not the file's. Before chunked
    planning the toolpath and the whole program were in memory at once: three times as much."""
    opt = PlanOptions(ik_block_rows=20_000)
    peaks, sizes = [], []
    for n in (100_000, 300_000):
        path = tmp_path / f"r{n}.gcode"
        path.write_text(_raster(n))
        plan_gcode(path, cell, opt, program_dir=tmp_path / "warm")          # imports, caches
        tracemalloc.start()
        try:
            res = plan_gcode(path, cell, opt, program_dir=tmp_path / f"plan{n}")
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        assert res.report.reachable and np.isfinite(res.estimate_s)
        sizes.append(sum(getattr(res.program, name).nbytes for name in COLUMNS))
    assert sizes[1] > 2.9 * sizes[0] and sizes[1] > 45e6
    assert peaks[1] < 1.3 * peaks[0] and peaks[1] < sizes[1], ([p / 1e6 for p in peaks], sizes[1] / 1e6)


def _rss_file_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("RssFile:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


@pytest.mark.slow                         # 1.1 s (not the fast tier)
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="resident pages are read from /proc")
def test_a_mapped_program_is_read_through_with_its_pages_given_back(cell: Cell, tmp_path: Path) -> None:
    path = tmp_path / "r.gcode"
    path.write_text(_raster(200_000))
    res = plan_gcode(path, cell, PlanOptions(), program_dir=tmp_path / "plan")
    prog = res.program
    program_mb = sum(getattr(prog, name).nbytes for name in COLUMNS) / 1e6
    base = _rss_file_mb()

    class Null:
        def write(self, text: str) -> int:
            return len(text)

    walks = {"artifact": lambda: sum(len(p) for p in program_artifact_pieces(prog)[1]),
             "times": lambda: program_times(prog, cell.robot, 1.0, StartState.at_joints(
                 cell.robot, prog.wobj, cell.home_q_rad), block_rows=50_000)}
    for fmt in ("csv", "rapid"):
        walks[fmt] = lambda fmt=fmt: write_export(prog, fmt, Null(), cell, t_end_s=res.t_end_s)
    for name, walk in walks.items():
        walk()
        assert _rss_file_mb() - base < 0.1 * program_mb, name     # what was read went back
    prog.q_rad.sum()                                              # read without giving back: resident
    assert _rss_file_mb() - base > 0.2 * program_mb
    prog.release_pages()
    assert _rss_file_mb() - base < 0.1 * program_mb


# -- the service ------------------------------------------------------------------------------------------

def test_the_planner_keeps_one_plan_and_serves_it_as_planned_in_memory(session, settings, cell: Cell,
                                                                       tmp_path: Path) -> None:
    gcode = tmp_path / "part.gcode"
    gcode.write_text(rich_gcode(n_layers=30, seed=7))
    planner = PlannerService(session, settings.cell, cell, data_dir=tmp_path / "planner")
    planner.start()
    args = replace(settings, mode="client").to_args()
    try:
        for k in range(2):
            out = tmp_path / f"out{k}.csv"
            assert main(["plan", str(gcode), "--csv", str(out), "--json", *args]) == 0
            plans = sorted(d.name for d in planner.plans_dir.iterdir())
            assert len(plans) == 1                             # the plan before is forgotten, its files gone
        local = plan_gcode(gcode, cell, PlanOptions(), filename="part.gcode")
        buf = io.StringIO()
        write_export(local.program, "csv", buf, cell, t_end_s=local.t_end_s)
        assert out.read_text() == buf.getvalue()
        program_id = next(iter(planner.recent))
        assert program_id == program_artifact(local.program, name="part.program").artifact_id
    finally:
        planner.close()
    assert not planner.plans_dir.exists()


def test_clients_send_without_a_shared_memory_pool() -> None:
    """A client's pool would be mapped by every service it sends to and never unmapped (32 MB a command)."""
    key = "transport/shared_memory/transport_optimization/enabled"
    client = json.loads(zenoh_config(SessionSettings(mode="client")).get_json(key))
    peer = json.loads(zenoh_config(SessionSettings(mode="peer")).get_json(key))
    assert client is False and peer is True


def test_rapid_names_a_speed_next_to_a_half(cell: Cell) -> None:
    """66.65 mm/s: np.round says 66.6, Python's round (the lookup) 66.7; the export used to fail (KeyError)."""
    res = plan_gcode("M83\nG1 Z0.3 F3000\nG1 X50 Y50 E0.1 F3999\nG1 X60 Y50 E0.1\n", cell)
    buf = io.StringIO()
    write_export(res.program, "rapid", buf, cell)
    assert "CONST speeddata vAM66_7 := [66.7," in buf.getvalue()


def test_a_write_error_of_the_program_files_reaches_the_planner_and_nothing_stays(tmp_path: Path) -> None:
    """The program's files are written by a thread of their own, a block behind: a full disk there is raised
    to the planner by its next append and by finish, and discarding leaves no file."""
    sink = FileSink(tmp_path / "cols")
    cols = {k: np.zeros((100, *shape), dtype) for k, (dtype, shape) in column_spec().items()}

    def full(_data: object) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    sink._files["xyz_mm"].write = full          # type: ignore[method-assign]
    sink.append(cols)
    with pytest.raises(OSError) as exc:
        for _ in range(3):
            sink.append(cols)
        sink.finish(np.eye(4), {})
    assert exc.value.errno == errno.ENOSPC
    with pytest.raises(OSError):                 # the files lack a block: never a program made of them
        sink.finish(np.eye(4), {})
    sink.discard()
    assert not (tmp_path / "cols").exists()


def test_the_program_files_hold_every_block_in_order(tmp_path: Path) -> None:
    sink = FileSink(tmp_path / "cols")
    blocks = [{k: np.full((n, *shape), n % 250, dtype) for k, (dtype, shape) in column_spec().items()}
              for n in (5, 3000, 7)]
    for cols in blocks:
        sink.append(cols)
    prog, _extra = sink.finish(np.eye(4), {})
    assert len(prog) == 3012
    np.testing.assert_array_equal(prog.xyz_mm[:, 0], np.repeat([5.0, 3000 % 250, 7.0], [5, 3000, 7]))
