"""core.threads: a short session is read, segmented and fitted in the caller's thread (a thread start
and hand-over per stage cost a 250 kB fleet session ~3 ms of its ~25)."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from accellog.core.threads import InlineExecutor, pool
from accellog.flows.fleet import pipeline_hash, session_task
from accellog.flows.fleet_sim import FleetSpec, simulate_fleet
from accellog.flows.pipeline import load_pipeline

PIPELINE = Path(__file__).resolve().parents[2] / "pipelines" / "fleet.toml"


def test_inline_executor_runs_at_submit_and_keeps_exceptions_in_the_future():
    calls: list[int] = []
    with pool(1, threaded=False) as ex:
        assert isinstance(ex, InlineExecutor)
        f = ex.submit(calls.append, 7)
        assert calls == [7] and f.done() and f.result() is None
        g = ex.submit(lambda: 1 / 0)
        assert g.done() and isinstance(g.exception(), ZeroDivisionError)

        def interrupted():
            raise KeyboardInterrupt

        with pytest.raises(KeyboardInterrupt):  # not stored: Ctrl-C stops the caller at once
            ex.submit(interrupted)


@pytest.fixture(scope="module")
def short_session(tmp_path_factory: pytest.TempPathFactory) -> str:
    out = tmp_path_factory.mktemp("short")
    simulate_fleet(FleetSpec(n_devices=1, sessions_per_device=1), out)
    return str(next(out.rglob("*.mcap")))


def test_a_short_session_runs_the_fleet_task_without_starting_a_thread(short_session, monkeypatch):
    spec = load_pipeline(PIPELINE)
    started: list[str] = []
    real_start = threading.Thread.start

    def counting_start(self):
        started.append(self.name)
        real_start(self)

    monkeypatch.setattr(threading.Thread, "start", counting_start)
    r = session_task(short_session, None, spec, pipeline_hash(spec))
    assert not r["rows"][0]["error"] and set(r["cals"]) == {"model3"}
    assert started == []
