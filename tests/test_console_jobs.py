"""The console lists every job not ended and the newest ended ones, however long the history has grown
(it asked for the first 100 in queue order: the oldest)."""
from __future__ import annotations

import time

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.services.supervisor import SupervisorService
from fabric.store.jobs import JobStore
from fabric.tui.joblist import HISTORY_SHOWN, console_jobs

pytestmark = pytest.mark.timeout(120)


def test_a_long_history_shows_its_newest_jobs(session, settings, tmp_path):
    store = JobStore(tmp_path / "supervisor" / "jobs.sqlite")
    t0 = time.time() - 10_000
    for k in range(HISTORY_SHOWN + 250):
        state = ("finished", "stopped", "failed")[k % 3]
        store.add(s.JobRecord(job_id=f"{k:012d}", filename=f"part{k}.gcode", source="gcode", state=state,
                              created_s=t0 + k, updated_s=t0 + k, ended_s=t0 + k + 1))
    store.close()
    sup = SupervisorService(session, settings.cell, data_dir=tmp_path / "supervisor")
    sup.start()
    try:
        with Client.connect(settings) as client:
            client.wait_alive(("supervisor",), deadline_s=20)
            listed = console_jobs(client)
            assert len(listed) == HISTORY_SHOWN
            assert [r.job_id for r in listed] == [f"{k:012d}" for k in range(250, HISTORY_SHOWN + 250)]
    finally:
        sup.close()
