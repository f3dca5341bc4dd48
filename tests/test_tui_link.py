"""The console's link to a cell: the temperatures are sampled (at most one sample each half second reaches the
screen), but a set point changed, by this console or another client, is posted at once."""
from __future__ import annotations

import threading

import pytest

from fabric import schemas as s
from fabric.tui.link import CellLink
from fabric.tui.messages import Telemetry

from support.tui_stub import StubClient

pytestmark = pytest.mark.timeout(60)


def temps(nozzle_c: float, nozzle_target_c: float, bed_target_c: float = 0.0) -> s.Temps:
    return s.Temps(nozzle_c=nozzle_c, nozzle_target_c=nozzle_target_c, bed_c=20.0, bed_target_c=bed_target_c)


def test_a_new_set_point_is_posted_at_once_and_the_samples_between_are_not():
    client = StubClient()
    posted: list[s.Temps] = []
    changed = threading.Condition()

    def post(msg) -> None:
        if isinstance(msg, Telemetry) and msg.topic == "temps":
            with changed:
                posted.append(msg.payload)
                changed.notify_all()

    link = CellLink(client, post)
    link.open()
    try:
        stream = client.subscribe("station", "temps")
        # back to back, as the station publishes them at 10 Hz and more often on a change
        for sample in (temps(20.0, 0.0), temps(20.5, 180.0, 55.0), temps(21.0, 180.0, 55.0), temps(21.5, 200.0, 55.0)):
            stream.put(sample)
        with changed:
            assert changed.wait_for(lambda: posted and posted[-1].nozzle_target_c == 200.0, timeout=10.0), \
                f"the last set point not posted: {posted}"
            assert [t.nozzle_c for t in posted] == [20.0, 20.5, 21.5]     # each change at once, the repeat not
    finally:
        link.close()
