"""The demo job: start the cell, print the bundled sample part on the twin, summarise, write artifacts.

    python -m fabric.demo [--out out/demo] [--rtf 0] [--model part.stl] [--profile robot-1.2mm]

Everything goes through the fabric exactly as an operator's would: the five
services run as separate processes, the job is submitted to the supervisor,
and the artifacts are fetched back from the services over Zenoh.
"""
from __future__ import annotations

import argparse
import queue
import shutil
import socket
import sys
import time
from dataclasses import replace
from pathlib import Path

from fabric import schemas as s
from fabric.cli.up import CellProcesses
from fabric.client import Client
from fabric.client.follow import follow_print
from fabric.programs import program_from_artifact
from fabric.schemas.states import PrintJob
from fabric.viz import toolpath_png
from fabric.wire.config import SessionSettings
from fabric.wire.errors import FabricError

__all__ = ["main", "sample_model", "run_demo"]

DATA = Path(__file__).parent / "data"


def sample_model() -> Path:
    """The bundled sample part."""
    return DATA / "sample_part.stl"


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def run_demo(client: Client, model: Path, out: Path, profile: str, backend: str, rtf: float,
             say=print) -> dict:
    """Submit ``model`` as a print job, run it to the end, write artifacts; returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    ext_sub = client.subscribe("station", "extrusion")
    try:
        acc = client.submit(s.JobSubmit(model=model.read_bytes(), filename=model.name, profile=profile,
                                        backend=backend, start=True, rtf=rtf))
        say(f"job {acc.job_id}: slice -> plan -> collision check -> load -> print")
        stages: list[str] = []

        def progress(rec: s.JobRecord) -> None:
            label = "prepared" if rec.prepared and rec.state == PrintJob.QUEUED else rec.state
            if label and (not stages or stages[-1] != label):
                stages.append(label)
                say(f"  {label} ...")
        client.wait_print_job(acc.job_id, lambda r: r.state.printing or r.state == PrintJob.LOADED, on_change=progress)
        end = follow_print(client, timeout_s=3600)
        rec = client.wait_print_job(acc.job_id, lambda r: False, timeout=60)     # its final record
        t_wall = time.monotonic() - t0
        info = client.time()
        last_ext = None
        try:
            while True:
                last_ext = ext_sub.get(timeout=0.3)
                if last_ext.t_sim_s >= end.t_sim_s:
                    break
        except queue.Empty:
            pass
    finally:
        ext_sub.close()

    plan, coll = rec.plan, rec.collisions
    assert plan is not None and coll is not None, "a printed job went through planning and the check"
    slice_res = client.slice_result(rec.gcode_id)
    (out / f"{model.stem}.gcode").write_bytes(client.artifact("slicer", rec.gcode_id).data)
    program = program_from_artifact(client.artifact("planner", rec.program_id))
    (out / f"{model.stem}.mod").write_bytes(client.export(rec.program_id, "rapid").data)
    (out / f"{model.stem}.csv").write_bytes(client.export(rec.program_id, "csv").data)
    (out / "toolpath.png").write_bytes(toolpath_png(program, title=model.stem))
    (out / "as-printed.stl").write_bytes(client.mesh("stl").data)
    summary = {
        "model": model.name, "profile": profile, "backend": backend, "end": end.kind,
        "layers": plan.layers, "moves": plan.moves, "targets": plan.targets,
        "print_time_s": info.total_s, "estimate_s": plan.estimate_s, "wall_s": t_wall,
        "collision_free": coll.collision_free, "collision_configs": coll.checked_configs,
        "min_clearance_mm": coll.min_distance_mm,
        "extruded_mm3": last_ext.extruded_mm3 if last_ext else float("nan"),
        "planned_mm3": plan.extruded_mm3, "sliced_mm3": slice_res.extruded_mm3,
        "model_volume_mm3": slice_res.model_volume_mm3, "out": str(out),
    }
    return summary


def print_summary(sm: dict, say=print) -> None:
    say("")
    say(f"printed {sm['model']} ({sm['profile']}, {sm['backend']} slicer): {sm['end']}")
    say(f"  layers            {sm['layers']}")
    say(f"  moves             {sm['moves']} ({sm['targets']} robot targets)")
    say(f"  print time        {sm['print_time_s']:.1f} s simulated (estimate {sm['estimate_s']:.1f} s), "
        f"{sm['wall_s']:.1f} s wall for the whole job")
    say(f"  collisions        {'none' if sm['collision_free'] else 'FOUND'} "
        f"({sm['collision_configs']} configurations, min clearance {sm['min_clearance_mm']:.1f} mm)")
    say(f"  extruded volume   {sm['extruded_mm3']:.0f} mm3 deposited by the twin (sliced {sm['sliced_mm3']:.0f}, "
        f"planned {sm['planned_mm3']:.0f}; the model is {sm['model_volume_mm3']:.0f} mm3 solid)")
    say(f"  artifacts         {sm['out']}/ (G-code, RAPID .mod, CSV, toolpath.png, as-printed.stl)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="tools/demo", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("out/demo"))
    p.add_argument("--model", type=Path, default=sample_model())
    p.add_argument("--profile", default="robot-1.2mm")
    p.add_argument("--backend", default="builtin")
    p.add_argument("--rtf", type=float, default=0.0, help="real-time factor (0 = as fast as possible)")
    a = p.parse_args(argv)
    settings = SessionSettings(connect=[f"tcp/127.0.0.1:{_free_port()}"], cell="demo")
    data = a.out / "data"                    # the cell's durable state: fresh for every demo run
    shutil.rmtree(data, ignore_errors=True)
    cell = CellProcesses(settings, log_dir=a.out / "logs", data_dir=data)
    print(f"starting the cell (5 services, logs in {a.out / 'logs'}) ...")
    try:
        cell.start(deadline_s=120)
        with Client.connect(replace(settings, mode="client")) as client:
            summary = run_demo(client, a.model, a.out, a.profile, a.backend, a.rtf)
        print_summary(summary)
        return 0 if summary["end"] == "finished" and summary["collision_free"] else 1
    except FabricError as err:
        print(f"demo failed [{err.code}]: {err.message}", file=sys.stderr)
        return 1
    finally:
        cell.stop()


if __name__ == "__main__":
    sys.exit(main())
