"""Every command at once: a storm of seeded operators (threads here, and processes of their own) drives the
supervisor's queue and the station for a bounded time against the whole cell as processes; afterwards the
supervisor's records and the station's event log must tell one consistent story.

Refusals are part of the game (``state``, ``not_found``, ``validation``: counted); an ``internal`` error, a
live service timing out (``unavailable``) or an exception that is not a typed fabric error is a failure.
Invariants checked once the cell has settled (no print, nothing being prepared, records and the event log
unchanged for a while):

* one record per job; every accepted submit has its record unless a remove of it succeeded, and a removed
  job stays removed;
* no job printed twice: at most one ``started`` event per job (this test never restarts at a layer);
* a record agrees with the station's events about its job (its state is what its last lifecycle event
  says; finished / stopped / printing / paused have the event), a record on the station agrees with the
  station's state and loaded job, and at most one job is on the station;
* the event log's ``seq`` has no gap;
* a job submitted without ``start`` was started only by an explicit ``job next`` naming it or a
  station ``start``; a job removed while it waited was never started.
"""
from __future__ import annotations

import contextlib
import itertools
import json
import os
import queue
import random
import subprocess
import sys
import threading
import time
import traceback
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

import pytest

from fabric import schemas as s
from fabric.client import Client
from fabric.wire.config import SessionSettings
from fabric.wire.errors import FabricError

pytestmark = pytest.mark.timeout(120)

STORM_S = 16.0                 # wall time of the storm
THREADS = 6                    # operators in this process
PROCESSES = 2                  # operators in processes of their own
MAX_SUBMITS = 12              # per operator (every job record is decoded on each `jobs`)
SETTLE_S = 40.0                # deadline for the cell to settle after the storm
STABLE_S = 2.5                 # settled: nothing changed for this long (> the supervisor's 1 s wake period)
REFUSALS = ("state", "not_found", "validation")
LIFECYCLE = {"started": "printing", "resumed": "printing", "recovered": "printing", "paused": "paused",
             "finished": "finished", "stopped": "stopped", "fault": "failed", "interrupted": "interrupted"}
FINAL = ("finished", "stopped", "failed")
ON_STATION = {"loaded": "ready", "printing": "printing", "paused": "paused", "interrupted": "interrupted"}
PREPARING = ("slicing", "planning", "checking")


def tiny_gcode(k: int) -> bytes:
    """Two small layers (a few seconds of simulated print, fractions of a second at max speed)."""
    lines = ["; filament_diameter = 2.85", "G21", "G90", "M83", "M104 S200", "M109 S200"]
    for layer in range(2):
        lines += [f";LAYER:{layer}", f"G1 Z{0.3 + 0.3 * layer:.2f} F600"]
        lines += [f"G1 X{100 + 3 * k + (i % 2) * 20} Y{100 + 2 * i} E0.5 F1800" for i in range(6)]
    return ("\n".join(lines) + "\n").encode()


# --- one operator -------------------------------------------------------------------------------------


class Operator:
    """Drives random commands with a seeded generator until a wall-clock deadline, logging every call."""

    def __init__(self, client: Client, name: str, seed: str, deadline: float, log: list[dict]) -> None:
        self.c, self.name, self.rng, self.deadline, self.log = client, name, random.Random(seed), deadline, log
        self.known: list[str] = []                     # job ids this operator has seen
        self.submitted = 0
        self.ops = [(self.submit, 6), (self.job_next, 9), (self.job_remove, 5), (self.job_move, 5),
                    (self.job_list, 5), (self.job_show, 4), (self.start, 6), (self.pause, 6), (self.resume, 6),
                    (self.stop, 6), (self.home, 3), (self.overrides, 3), (self.rtf, 4), (self.ready, 2),
                    (self.state, 4), (self.time, 2), (self.position, 2), (self.events, 3), (self.collisions, 2)]
        if hasattr(client, "clear_plate"):             # the station owns the part on the plate (newer stations)
            self.ops.append((self.clear_plate, 3))

    def run(self) -> None:
        funcs, weights = [op for op, _ in self.ops], [w for _, w in self.ops]
        while time.time() < self.deadline:
            op = self.rng.choices(funcs, weights)[0]
            if op == self.submit and self.submitted >= MAX_SUBMITS:
                op = self.job_list
            self._call(op.__name__, op)
            time.sleep(self.rng.uniform(0.0, 0.03))

    def _call(self, op: str, fn) -> None:
        entry: dict = {"who": self.name, "op": op, "t0": time.time()}
        try:
            entry.update(fn() or {})
            entry["outcome"] = "ok"
        except FabricError as err:
            entry["outcome"] = err.code
            entry["message"] = err.message
        except Exception:  # noqa: BLE001 - not a typed fabric error: a failure, recorded and asserted on
            entry["outcome"] = "exception"
            entry["message"] = traceback.format_exc(limit=3)
        entry["t1"] = time.time()
        self.log.append(entry)

    def _job(self) -> str:
        return self.rng.choice(self.known) if self.known else "000000000000"

    def _rtf(self) -> float:
        return self.rng.choice([0.0, 0.0, 10.0, 40.0])

    # queue
    def submit(self):
        self.submitted += 1
        start, rtf, k = self.rng.random() < 0.5, self._rtf(), self.rng.randrange(4)
        entry = {"start": start, "rtf": rtf}
        try:
            acc = self.c.submit(s.JobSubmit(model=tiny_gcode(k), filename=f"{self.name}-{k}.gcode", source="gcode",
                                            start=start, rtf=rtf))
        except FabricError as err:
            err.message = f"{err.message} (submit start={start})"
            raise
        self.known.append(acc.job_id)
        return {**entry, "job_id": acc.job_id}

    def job_next(self):
        ack = self.c.job_next()
        return {"message": ack.message, "state": ack.state}

    def job_remove(self):
        job = self._job()
        entry = {"job_id": job}
        try:
            ack = self.c.job_remove(job)
        except FabricError as err:
            err.message = f"{err.message} (remove {job})"
            raise
        return {**entry, "state": ack.state, "message": ack.message}

    def job_move(self):
        job = self._job()
        self.c.job_move(job, self.rng.randrange(3))
        return {"job_id": job}

    def job_list(self):
        jobs = self.c.jobs().jobs
        self.known.extend(j.job_id for j in jobs if j.job_id not in self.known)
        return {"n": len(jobs)}

    def job_show(self):
        return {"job_id": self.c.job(self._job()).job_id}

    # station
    def start(self):
        ack = self.c.start(rtf=self.rng.choice([None, 0.0, 10.0]))
        return {"message": ack.message, "state": ack.state}

    def pause(self):
        return {"state": self.c.pause().state}

    def resume(self):
        return {"state": self.c.resume(rtf=self.rng.choice([None, 0.0])).state}

    def stop(self):
        return {"state": self.c.stop().state}

    def clear_plate(self):
        return {"state": self.c.clear_plate().state}

    def home(self):
        return {"state": self.c.home().state}

    def overrides(self):
        return {"state": self.c.overrides(speed_r=self.rng.choice([0.5, 1.0, 2.0]),
                                          flow_r=self.rng.choice([0.9, 1.0])).state}

    def rtf(self):
        return {"state": self.c.set_rtf(self.rng.choice([0.0, 10.0, 40.0])).state}

    def ready(self):
        return {"ready": self.c.ready().ready}

    def state(self):
        return {"state": self.c.state().state}

    def time(self):
        return {"state": self.c.time().state}

    def position(self):
        self.c.position()

    def events(self):
        last = self.c.events(0, limit=1).last_seq
        self.c.events(max(1, last - self.rng.randrange(50)))

    def collisions(self):
        return {"collision_free": self.c.collisions().collision_free}


def drive_process(connect: list[str], cell: str, mode: str, seed: str, deadline: float, out: str) -> None:
    """An operator in a process of its own; its log is written to ``out`` (JSON lines)."""
    log: list[dict] = []
    settings = SessionSettings(mode=mode, connect=connect, cell=cell)
    try:
        with Client.connect(settings) as client:
            Operator(client, f"proc-{seed}", f"conc-proc-{seed}", deadline, log).run()
    except Exception:  # noqa: BLE001 - the session itself failed: recorded, the test fails on it
        log.append({"who": f"proc-{seed}", "op": "session", "t0": time.time(), "t1": time.time(),
                    "outcome": "exception", "message": traceback.format_exc(limit=3)})
    with open(out, "w") as f:
        for entry in log:
            f.write(json.dumps(entry) + "\n")


# --- the test -----------------------------------------------------------------------------------------


def _all_jobs(c: Client) -> list[s.JobRecord]:
    """Every record, page by page where the supervisor pages them."""
    first = c.jobs()
    jobs = list(first.jobs)
    while getattr(first, "total", -1) >= 0 and len(jobs) < first.total:
        page = c.jobs(offset=len(jobs))
        if not page.jobs:
            break
        jobs += page.jobs
    return jobs


def _all_events(c: Client) -> list[s.Event]:
    out: list[s.Event] = []
    since = 1
    while True:
        page = c.events(since, limit=10_000)
        out += page.events
        if not page.events or page.next_seq <= since:
            return out
        since = page.next_seq


def _settle(c: Client, deadline_s: float) -> tuple[list[s.JobRecord], s.StationState]:
    """Stop any print and wait until nothing prints, nothing is being prepared and neither the records nor
    the station's event log have changed for ``STABLE_S``."""
    c.set_rtf(0.0)                                          # whatever starts from here ends at once
    end = time.monotonic() + deadline_s
    last, since = None, time.monotonic()
    while True:
        assert time.monotonic() < end, f"the cell did not settle within {deadline_s:g} s"
        st = c.state()
        if st.state in ("printing", "paused"):
            try:
                c.stop()
            except FabricError as err:                       # it ended (or paused) meanwhile
                assert err.code == "state", err
            since, last = time.monotonic(), None
            continue
        jobs = _all_jobs(c)
        last_seq = c.events(0, limit=1).last_seq
        busy = st.state == "moving" or any(
            j.state in PREPARING or (j.state == "queued" and not j.prepared) for j in jobs)
        key = (st.state, st.job_id, last_seq,
               tuple((j.job_id, j.state, j.prepared, j.waiting_for, j.updated_s) for j in jobs))
        if key != last or busy:
            last, since = key, time.monotonic()
        elif time.monotonic() - since >= STABLE_S:
            return jobs, st
        assert time.monotonic() < end, f"the cell did not settle within {deadline_s:g} s: {st.state}, " \
            f"{[(j.job_id, j.state, j.stage) for j in jobs if j.state not in FINAL and j.waiting_for != 'queue']}"
        time.sleep(0.25)                                     # polling, until the deadline above


def _cut(items: list, n: int = 12, tail: bool = False) -> str:
    """A long list in a message: its first (or last) ``n`` items."""
    if len(items) <= n:
        return str(items)
    return f"[... {items[-n:]}]" if tail else f"{items[:n]} ... ({len(items)} in all)"


def _violations(c: Client, log: list[dict], pre_jobs: set[str], received: dict[int, float]) -> list[str]:
    jobs, st = _settle(c, SETTLE_S)
    events = _all_events(c)
    bad: list[str] = []

    # the event log: gap-free
    seqs = [e.seq for e in events]
    if seqs and seqs != list(range(seqs[0], seqs[0] + len(seqs))):
        gaps = [(a, b) for a, b in itertools.pairwise(seqs) if b != a + 1]
        bad.append(f"station event seq has gaps: {gaps[:10]}")

    # one record per job; accepted jobs kept unless removed, removed ones stay removed
    ids = [j.job_id for j in jobs]
    dup = [j for j, n in Counter(ids).items() if n > 1]
    if dup:
        bad.append(f"duplicate job records: {dup}")
    records = {j.job_id: j for j in jobs}
    ok = [e for e in log if e["outcome"] == "ok"]
    accepted = {e["job_id"]: e for e in ok if e["op"] == "submit"}
    removed = {e["job_id"]: e for e in ok if e["op"] == "job_remove"}
    for job in accepted:
        if job not in records and job not in removed:
            bad.append(f"accepted job {job} has no record and was never removed")
        if job in records and job in removed:
            bad.append(f"job {job} was removed ({removed[job]['message']!r}) but has a record again: "
                       f"{records[job].state} ({records[job].stage})")
    unknown = set(records) - set(accepted) - pre_jobs
    if unknown:
        bad.append(f"records of jobs nobody had accepted: {sorted(unknown)}")

    # the station's events per job
    by_job: dict[str, list[s.Event]] = defaultdict(list)
    for e in events:
        job = e.data.get("job_id", "") if isinstance(e.data, dict) else ""
        if job and e.kind in LIFECYCLE:
            by_job[job].append(e)
    twice = {job: evs for job, evs in by_job.items() if sum(e.kind == "started" for e in evs) > 1}
    for job, evs in list(twice.items())[:3]:                 # the first few in full, then how many
        starts = [e for e in evs if e.kind == "started"]
        bad.append(f"job {job} printed {len(starts)} times: started events (seq, from_row) "
                   f"{_cut([(e.seq, e.data.get('from_row')) for e in starts])}; its lifecycle "
                   f"{_cut([(e.seq, e.kind) for e in evs])}; record "
                   f"{records[job].state if job in records else 'removed'}")
    if len(twice) > 3:
        bad.append(f"... {len(twice)} jobs printed more than once in all: "
                   f"{ {job: sum(e.kind == 'started' for e in evs) for job, evs in twice.items()} }")
    for job, rec in records.items():
        evs = by_job.get(job, [])
        expect = None
        for e in evs:                                         # what the events say the job's state is
            if expect in FINAL and e.kind != "started":
                continue
            expect = LIFECYCLE[e.kind]
        if expect is None:
            if rec.state in ("printing", "paused", "finished", "stopped", "interrupted"):
                bad.append(f"job {job} is {rec.state} but the station has no lifecycle event for it")
        elif rec.state != expect:
            bad.append(f"job {job}'s record says {rec.state} ({rec.stage!r}) but its events say {expect}: "
                       f"{_cut([(e.seq, e.kind) for e in evs], tail=True)}")

    # what is on the station
    on_station = [r for r in jobs if r.state in ON_STATION]
    if len(on_station) > 1:
        bad.append(f"{len(on_station)} jobs on the station: {[(r.job_id, r.state) for r in on_station]}")
    for r in on_station:
        if st.job_id != r.job_id or st.state != ON_STATION[r.state]:
            bad.append(f"job {r.job_id} is {r.state} but the station is {st.state} with job {st.job_id!r}")
    if st.state in ("ready", "printing", "paused", "interrupted") and st.job_id in records:
        rec = records[st.job_id]
        if ON_STATION.get(rec.state) != st.state:
            bad.append(f"the station is {st.state} with job {st.job_id} whose record says {rec.state} "
                       f"({rec.stage!r})")

    # who started what: a job submitted without start needs a job next naming it or a station start
    nexts = [e for e in ok if e["op"] == "job_next"]
    station_starts = sorted(e["t0"] for e in ok if e["op"] == "start")
    used: set[int] = set()
    for e in sorted((e for e in events if e.kind == "started"), key=lambda e: e.seq):
        job = e.data.get("job_id", "")
        if job not in accepted or accepted[job]["start"]:
            continue
        seen_s = received.get(e.seq, float("inf"))
        if any(n["t0"] <= seen_s and job in n["message"] for n in nexts):
            continue
        k = next((i for i, t in enumerate(station_starts) if t <= seen_s and i not in used), None)
        if k is None:
            bad.append(f"job {job} was submitted without start and started (event {e.seq}) with no job next "
                       f"naming it and no station start before")
        else:
            used.add(k)

    # a job removed while it waited is never started
    for job, e in removed.items():
        if e["state"] in ("queued", *PREPARING) and any(ev.kind == "started" for ev in by_job.get(job, [])):
            bad.append(f"job {job} was removed while {e['state']} ({e['message']!r}) and yet started: "
                       f"{[(ev.seq, ev.kind) for ev in by_job[job]]}")
    return bad


@pytest.fixture
def client(running_cell):
    with Client.connect(running_cell.settings) as c:
        c.wait_alive(deadline_s=30)
        yield c


def test_a_storm_of_every_command_leaves_records_and_events_consistent(running_cell, client, tmp_path):
    settings = running_cell.settings
    pre_jobs = {j.job_id for j in _all_jobs(client)}       # left by other tests of the session
    received: dict[int, float] = {}                          # event seq -> wall time it reached this process
    sub = client.subscribe("station", "events")
    stop_sub = threading.Event()

    def stamp() -> None:
        while not stop_sub.is_set():
            try:
                ev = sub.get(timeout=0.2)
            except queue.Empty:
                continue
            received.setdefault(ev.seq, time.time())
    stamper = threading.Thread(target=stamp, daemon=True)
    stamper.start()

    deadline = time.time() + STORM_S
    tests_dir = str(Path(__file__).parent)
    procs = []
    for k in range(PROCESSES):
        out = tmp_path / f"proc{k}.jsonl"
        code = (f"import sys; sys.path.insert(0, {tests_dir!r}); import test_concurrency as t; "
                f"t.drive_process({settings.connect!r}, {settings.cell!r}, {('peer', 'client')[k % 2]!r}, "
                f"{str(k)!r}, {deadline!r}, {str(out)!r})")
        procs.append((subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE,
                                       stderr=subprocess.STDOUT, text=True, cwd=os.getcwd()), out))
    log: list[dict] = []
    with contextlib.ExitStack() as stack:              # two sessions for the threads: a client and a peer
        clients = [stack.enter_context(Client.connect(replace(settings, mode=mode))) for mode in ("client", "peer")]
        ops = [Operator(clients[k % 2], f"thread-{k}", f"conc-thread-{k}", deadline, log) for k in range(THREADS)]
        threads = [threading.Thread(target=op.run, name=f"storm-{k}") for k, op in enumerate(ops)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=STORM_S + 180)
        assert not any(t.is_alive() for t in threads), "an operator thread is stuck"
    for proc, out in procs:
        text, _ = proc.communicate(timeout=180)
        assert proc.returncode == 0, text
        log += [json.loads(line) for line in out.read_text().splitlines()]

    failures = [e for e in log if e["outcome"] not in ("ok", *REFUSALS)]
    counts = Counter((e["op"], e["outcome"]) for e in log)
    summary = (f"{len(log)} calls by {THREADS} threads and {PROCESSES} processes in {STORM_S:g} s: "
               f"{sorted(counts.items())}")
    print(summary)
    assert sum(1 for e in log if e["op"] == "submit" and e["outcome"] == "ok") >= 5, summary

    bad = _violations(client, log, pre_jobs, received)
    if bad:                                  # a record behind the events? settle once more and look again
        bad = _violations(client, log, pre_jobs, received)
    stop_sub.set()
    stamper.join(timeout=5)
    sub.close()
    problems = [f"{e['who']} {e['op']}: {e['outcome']}: {e.get('message', '')}" for e in failures] + bad
    if problems:                                   # the evidence, for whoever reads the failure
        dump = tmp_path / "storm.json"
        dump.write_text(json.dumps({
            "log": sorted(log, key=lambda e: e["t0"]), "received": received,
            "events": [s.to_plain(e) for e in _all_events(client)],
            "jobs": [s.to_plain(j) for j in _all_jobs(client)], "station": s.to_plain(client.state()),
            "cell_logs": str(running_cell.log_dir)}, indent=1, default=str))
        problems.append(f"evidence: {dump}; service logs: {running_cell.log_dir}")
    assert not problems, "\n".join([summary, *problems])
