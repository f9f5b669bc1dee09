"""A gap in time is an event the integrating stages respect (issue 46): integrating straight across
a 1e6 s gap put a static test 8e5 m away "at 60 s" without a word, and replay slept through it.
Every integral goes through core.timeseries.cumtrapz, which refuses a step longer than MAX_GAP_S
with one line naming it; the part before the gap (--until-s) is evaluated as before."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.timeseries import MAX_GAP_S, cumtrapz
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session
from accellog.store.writer import write_session


def test_cumtrapz_refuses_a_gap_also_across_blocks():
    t = np.arange(10.0)
    y = np.ones((10, 3))
    np.testing.assert_array_equal(cumtrapz(t, y), cumulative_trapezoid(y, t, axis=0, initial=0))
    t_gap = np.r_[t[:5], t[5:] + 1e6]
    with pytest.raises(InputError, match=r"1e\+06 s gap in the time stamps after t = 4\.000 s"):
        cumtrapz(t_gap, y)
    with pytest.raises(InputError, match=r"after t = 9\.000 s"):  # the step from the previous block
        cumtrapz(t[:3] + 9.0 + MAX_GAP_S + 1.0, y[:3], np.zeros(3), prev=(9.0, y[0]))
    cumtrapz(t[:3] + 9.0 + MAX_GAP_S, y[:3], np.zeros(3), prev=(9.0, y[0]))  # the limit itself is no gap


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("gaps")
    simulate(Scenario(protocol="six", hold_s=4.0, move_s=1.0, sample_rate_hz=200.0, seed=5), d / "six.mcap")
    assert main(["fit", str(d / "six.mcap"), "-o", str(d / "cal.json")]) == 0
    simulate(Scenario(protocol="+z", hold_s=40.0, sample_rate_hz=200.0, seed=6), d / "still.mcap")
    s = read_session(d / "still.mcap")
    t = s.t_s.copy()
    t[t.size // 2 :] += 1e6
    write_session(d / "gap.mcap", dataclasses.replace(s, t_s=t))
    return d, float(s.t_s[t.size // 2 - 1])


@pytest.mark.parametrize(
    "cmd",
    [
        ["evaluate", "{gap}", "--cal", "{cal}", "--json"],
        ["integrate", "{gap}", "--cal", "{cal}", "-o", "{out}.csv"],
        ["drift", "{gap}", "--cal", "{cal}", "-o", "{out}.json"],
        ["replay", "{gap}", "--cal", "{cal}", "--speed", "10", "--up", "+z"],
    ],
    ids=["evaluate", "integrate", "drift", "replay"],
)
def test_integrating_stages_refuse_a_gap_in_one_line(sessions, cmd, capsys):
    d, t_before = sessions
    args = [c.format(gap=d / "gap.mcap", cal=d / "cal.json", out=d / cmd[0]) for c in cmd]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "1e+06 s gap in the time stamps" in err[0], err
    assert f"after t = {t_before:.3f} s" in err[0]
    assert not list(d.glob(f"{cmd[0]}.*"))  # nothing written


def test_the_part_before_the_gap_is_evaluated(sessions, capsys):
    d, t_before = sessions
    assert main(["evaluate", str(d / "gap.mcap"), "--cal", str(d / "cal.json"), "--until-s", f"{t_before:g}",
                 "--json"]) == 0  # fmt: skip
