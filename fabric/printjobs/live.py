"""A print job's figures while it prints, from the station's state (a pure function: the supervisor applies it).

The station's events move a job's record at its lifecycle's steps and at each new layer; between them the
record would say nothing of how far the print is. The station publishes its state (progress, volume deposited,
layer, simulated clock) at least twice a second during a print; the supervisor takes the last one every
:data:`LIVE_PERIOD_S` and, as one step of its writer, writes its figures onto the record of the job printing
(``progress_r``, ``deposited_mm3`` and the running run's share of it, ``layer``, the durations so far), which
is saved and published on ``supervisor/jobs`` like any change. So ``job list``, ``job show`` and whoever
follows the jobs stream see the print advance, at most :data:`LIVE_PERIOD_S` behind, from the one record
(durable: a supervisor restarted mid-print starts from figures at most that old). The events still decide the
state and the final figures: a state of another job, of a job no longer printing, or older than the record is
ignored.
"""
from __future__ import annotations

from fabric import schemas as s
from fabric.printjobs.events import run_share_mm3
from fabric.schemas.states import PrintJob

__all__ = ["LIVE_PERIOD_S", "apply_live"]

LIVE_PERIOD_S = 2.0


def apply_live(rec: s.JobRecord, st: s.StationState, wall_s: float) -> bool:
    """Write the station's figures ``st`` onto ``rec`` while that job prints; True when the record changed."""
    if rec.state != PrintJob.PRINTING or not st.state.printing or st.job_id != rec.job_id:
        return False
    seg = rec.segments[-1] if rec.segments and not rec.segments[-1].ended else None
    if seg is None or st.t_sim_s < seg.t_sim_start_s:
        return False                                  # a state from before this run began
    before = (rec.progress_r, rec.deposited_mm3, rec.layer, rec.sim_elapsed_s)   # the run's share follows these
    rec.progress_r = min(max(float(st.progress_r), 0.0), 1.0)
    rec.deposited_mm3 = max(float(st.deposited_mm3), 0.0)
    seg.deposited_mm3 = run_share_mm3(rec, seg)
    if st.layer > rec.layer:
        rec.layer = int(st.layer)
        seg.last_layer = max(seg.last_layer, int(st.layer))
        rec.stage = f"printing layer {st.layer + 1}"
    seg.sim_s = max(float(st.t_sim_s) - seg.t_sim_start_s, seg.sim_s)
    rec.sim_elapsed_s = sum(x.sim_s for x in rec.segments)
    rec.wall_elapsed_s = sum(max((x.ended_s or wall_s) - x.started_s, 0.0) for x in rec.segments)
    return (rec.progress_r, rec.deposited_mm3, rec.layer, rec.sim_elapsed_s) != before
