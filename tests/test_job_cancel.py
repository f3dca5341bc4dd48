"""A print job that fails or is removed cancels the slicing or planning job it started (issue 38): `job submit
sample_part.stl --layers curved` failed after 180 s and the slicer went on slicing for minutes.

The job runner's cancel (``<service>/cmd/cancel``): a queued job never runs, a running one fails at its next
step; the supervisor's preparation cancels what it started when its print job fails (its stage's time ran out)
or is removed (the wait for the slicer stops at once); and the real slicer stops a curved slice it was asked to
cancel. Services over the memory fabric (the fast tier)."""
from __future__ import annotations

import queue
import threading
from collections.abc import Callable

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.samples import SAMPLES_DIR
from fabric.schemas.states import Job as JobState
from fabric.server.jobs import Job, JobRunner
from fabric.server.service import Service
from fabric.services.slicer import SlicerService
from fabric.services.supervisor import SupervisorService
from fabric.wire.errors import NotFound, ServiceUnavailable, StateError

pytestmark = pytest.mark.timeout(120)

CELL = "cell1"
WAIT_S = 20.0            # a deadline for what happens at once; never reached when the feature works
STEP_S = 0.01            # one step of a stand-in job's work


def _endless(started: threading.Event, ended: queue.Queue) -> tuple[Callable[[Job], str], threading.Event]:
    """A job that works in steps until it is stopped: it says when it started, and how it ended."""
    give_up = threading.Event()           # the test's own bound: a job nobody cancels ends by itself

    def work(job: Job) -> str:
        started.set()
        try:
            while not give_up.wait(STEP_S):
                job.progress(0.5, "working")
            return "never cancelled"
        except BaseException as exc:
            ended.put(exc)
            raise
    return work, give_up


def test_a_queued_job_never_runs_and_a_running_one_fails_at_its_next_step():
    runner = JobRunner("slicer", None)
    try:
        started, ended = threading.Event(), queue.Queue()
        work, give_up = _endless(started, ended)
        running = runner.submit("slice", work)
        ran_second = threading.Event()
        queued = runner.submit("slice", lambda job: ran_second.set() or "ran")
        assert started.wait(WAIT_S)

        st = runner.cancel(queued.job_id, "print job A was removed")
        assert st.state == JobState.FAILED and st.error.code == "state"
        assert st.error.message == f"job {queued.job_id} was cancelled: print job A was removed"
        runner.cancel(running.job_id, "print job B failed")
        exc = ended.get(timeout=WAIT_S)                    # the work unwound from its next step
        assert isinstance(exc, StateError) and exc.details["reason"] == "print job B failed"
        give_up.set()
        done = threading.Event()
        runner.submit("slice", lambda job: done.set() or "after")
        assert done.wait(WAIT_S)                           # the worker went on, past the cancelled queued job
        assert not ran_second.is_set()
        assert runner.get(running.job_id).state == JobState.FAILED
        assert "was cancelled: print job B failed" in runner.get(running.job_id).error.message
        after = runner.cancel(running.job_id, "again")     # an ended job stays as it was
        assert after.error.details["reason"] == "print job B failed"
        with pytest.raises(NotFound):
            runner.cancel("nosuchjob")
    finally:
        runner.close()


class EndlessSlicer(Service):
    """A slicer whose slices never end by themselves (a curved slice taking longer than the job's time)."""

    name = "slicer"
    partial = True

    def __init__(self, session, cell: str) -> None:
        super().__init__(session, cell)
        self.jobs = JobRunner("slicer", self.publisher("progress", lossless=True))
        self.started, self.ended = threading.Event(), queue.Queue()
        self.work, self.give_up = _endless(self.started, self.ended)
        self.handle("slice", lambda req: s.JobAccepted(job_id=self.jobs.submit("slice", self.work).job_id,
                                                       kind="slice"))
        self.handle("job", lambda q: self.jobs.get(q.job_id))
        self.handle("cancel", lambda q: self.jobs.cancel(q.job_id, q.reason))
        self.serve_pins()

    def close(self) -> None:
        self.give_up.set()
        super().close()
        self.jobs.close()


@pytest.fixture
def cell(memory_fabric):
    services = [SupervisorService(memory_fabric.session(), CELL), EndlessSlicer(memory_fabric.session(), CELL)]
    for svc in services:
        svc.start()
    client = Client(memory_fabric.session(), CELL)
    client.wait_alive(("supervisor", "slicer"), deadline_s=WAIT_S)
    yield client, services[0], services[1]
    for svc in reversed(services):
        svc.close()


def _submit(client: Client) -> str:
    data = (SAMPLES_DIR / "sample_part.stl").read_bytes()
    return client.submit(s.JobSubmit(model=data, filename="sample_part.stl", layers="curved")).job_id


def test_a_print_job_removed_while_slicing_cancels_its_slice_at_once(cell):
    client, _supervisor, slicer = cell
    job_id = _submit(client)
    assert slicer.started.wait(WAIT_S)
    assert client.job_remove(job_id).ok
    exc = slicer.ended.get(timeout=WAIT_S)                 # within a step of the removal, not when it gives up
    assert isinstance(exc, StateError) and exc.details["reason"] == f"print job {job_id} was removed"
    assert not slicer.give_up.is_set()


def test_a_print_job_whose_slicing_runs_out_of_time_fails_and_cancels_its_slice(cell):
    client, supervisor, slicer = cell
    supervisor.preparer.budget_s = 1.0                     # the job's time for a stage (180 s in service)
    job_id = _submit(client)
    with pytest.raises(ServiceUnavailable, match="slicing did not complete within 1 s"):
        client.wait_print_job(job_id, lambda rec: False, timeout=WAIT_S)
    exc = slicer.ended.get(timeout=WAIT_S)
    assert isinstance(exc, StateError)
    assert exc.details["reason"].startswith(f"print job {job_id} failed: slicing did not complete within 1 s")
    assert client.job(job_id).state == "failed"


def test_the_slicer_stops_a_curved_slice_it_is_asked_to_cancel(memory_fabric):
    """The real slicer: the bundled sample part sliced curved (about 10 s) is cancelled once it is under way
    and fails with the reason, at a layer, long before its end."""
    slicer = SlicerService(memory_fabric.session(), CELL, (250.0, 250.0), 250.0)
    slicer.start()
    try:
        client = Client(memory_fabric.session(), CELL)
        client.wait_alive(("slicer",), deadline_s=WAIT_S)
        data = (SAMPLES_DIR / "sample_part.stl").read_bytes()
        acc = client.slice(s.SliceRequest(model=data, filename="sample_part.stl", layers="curved"))
        under_way = threading.Event()
        progress = client.subscribe("slicer", "progress")
        try:
            while not under_way.is_set():
                st = progress.get(timeout=WAIT_S)
                if st.job_id == acc.job_id and st.progress_r > 0.5:     # laying toolpaths, layer by layer
                    under_way.set()
        finally:
            progress.close()
        client.cancel_job("slicer", acc.job_id, "print job X was removed")
        with pytest.raises(StateError, match="was cancelled: print job X was removed"):
            client.wait_job("slicer", acc.job_id, timeout=WAIT_S)
        assert client.call("slicer", "job", s.JobQuery(job_id=acc.job_id)).progress_r < 0.95
    finally:
        slicer.close()
