"""Fault injection as a test tier: kill -9 of each service at a seeded random instant of a job, a whole
cell killed mid-print, concurrent submits. The long version (20 instants per service) is
tools/bench/fault_bench.py."""
from __future__ import annotations

import random
import threading

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.demo import sample_model

from support.faults import PROFILE, SupervisedCell, read_csv, reference_beads, run_with_fault, same_beads, wait_state
from support.loopback import make_settings

pytestmark = [pytest.mark.timeout(300), pytest.mark.slow]


@pytest.mark.parametrize("service", ["station", "supervisor", "planner", "slicer"])
def test_kill_9_at_a_random_instant_loses_nothing(service, tmp_path):
    delay_s = random.Random(f"ci-{service}").uniform(0.0, 0.5)
    with SupervisedCell(make_settings(), tmp_path / "data", tmp_path / "logs") as sc:
        run = run_with_fault(sc, service, delay_s)
        with Client.connect(sc.settings) as client:
            want = reference_beads(client, run.program_id)
            assert client.artifact("planner", run.program_id).data                  # no artifact lost
            assert client.artifact("slicer", run.record.gcode_id).data
            assert [j.job_id for j in client.jobs().jobs] == [run.record.job_id]    # no job lost or doubled
    assert run.record.state == "finished", (run.record.state, run.record.reason, sc.log)
    got = read_csv(run.beads_csv)
    assert same_beads(got, want), (service, run.killed_in, got.shape, want.shape)
    assert run.record.deposited_mm3 == pytest.approx(want[:, 6].sum(), rel=1e-9)


def test_the_whole_cell_killed_mid_print_comes_back_and_finishes(tmp_path):
    settings = make_settings()
    with SupervisedCell(settings, tmp_path / "data", tmp_path / "logs") as sc:
        with Client.connect(sc.settings) as client:
            acc = client.submit(s.JobSubmit(model=sample_model().read_bytes(), filename="sample_part.stl",
                                            profile=PROFILE, start=True, rtf=200.0))
            wait_state(client, acc.job_id, ("printing",), 120.0)
            client.wait_print_job(acc.job_id, lambda r: r.layer >= 2, timeout=120)
        sc.kill_all()
    with SupervisedCell(settings, tmp_path / "data", tmp_path / "logs") as sc:
        with Client.connect(sc.settings) as client:
            rec = wait_state(client, acc.job_id, ("interrupted",), 60.0)
            assert rec.layer >= 2 and "restarted" in rec.reason
            assert client.state().state == "interrupted"
            client.recover(rtf=0)
            rec = wait_state(client, acc.job_id, ("finished",), 120.0)
            got = read_csv(client.mesh("csv").data)
            want = reference_beads(client, rec.program_id)
    assert same_beads(got, want)


def test_concurrent_submits_queue_and_never_overwrite(tmp_path):
    model = sample_model().read_bytes()
    with SupervisedCell(make_settings(), tmp_path / "data", tmp_path / "logs") as sc:
        with Client.connect(sc.settings) as client:
            ids: list[str] = []
            lock = threading.Lock()

            def submit(k: int) -> None:
                acc = client.submit(s.JobSubmit(model=model, filename=f"part{k}.stl", profile=PROFILE,
                                                start=True, rtf=0.0))
                with lock:
                    ids.append(acc.job_id)
            threads = [threading.Thread(target=submit, args=(k,)) for k in range(3)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            assert len(set(ids)) == 3
            ids = [j.job_id for j in client.jobs().jobs]          # queue order: the order they arrived in
            assert len(ids) == 3
            first = wait_state(client, ids[0], ("finished",), 180.0)
            # the second job waits for the station until the supervisor has seen the first finish, then for the
            # plate (the first part is still on it); the third waits for the queue
            others = [client.wait_print_job(j, lambda r: r.waiting_for in ("plate", "queue"), timeout=180)
                      for j in ids[1:]]
            assert [(r.state, r.waiting_for) for r in others] == [("queued", "plate"), ("queued", "queue")]
            assert "job next" in others[0].stage
            assert client.state().program_id == first.program_id          # the station kept the first job
            nxt = client.job_next()
            assert ids[1] in nxt.message and nxt.state in ("loaded", "printing", "finished")
            wait_state(client, ids[1], ("finished",), 180.0)
            states = {j.job_id: j.state for j in client.jobs().jobs}
            assert states == {ids[0]: "finished", ids[1]: "finished", ids[2]: "queued"}
            assert client.job_remove(ids[2]).ok
            assert [j.job_id for j in client.jobs().jobs] == ids[:2]
