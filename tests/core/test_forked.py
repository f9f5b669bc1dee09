"""core.forked: a call run in a forked child comes back as if it had run in-process."""

from __future__ import annotations

import os
import signal
import time
import warnings

import pytest

from accellog.core import forked, notices
from accellog.core.errors import DataIntegrityWarning, InputError


@pytest.fixture
def fork_on(monkeypatch):
    """Forking allowed and forced (even on one core)."""
    monkeypatch.setenv(forked.ENV_SWITCH, "1")
    with forked.allowed():
        yield


def _pid_and(x):
    return os.getpid(), x


def test_the_value_comes_from_a_child(fork_on):
    with forked.started(_pid_and, {"a": [1, 2]}) as p:
        assert p.forked
        pid, x = p.result()
    assert pid != os.getpid()
    assert x == {"a": [1, 2]}


def _fails():
    raise InputError("hold 3 is not still", where="s.mcap")


def test_an_accellog_error_is_raised_as_it_is(fork_on):
    with forked.started(_fails) as p, pytest.raises(InputError, match=r"^s.mcap: hold 3 is not still$"):
        p.result()


def _warns_and_notes():
    warnings.warn("s.mcap: chunk 4 skipped", DataIntegrityWarning, stacklevel=1)
    notices.note("truncated file recovered")
    return 7


def test_warnings_and_notes_reach_the_parent(fork_on):
    notices.take()
    with forked.started(_warns_and_notes) as p, pytest.warns(DataIntegrityWarning, match="chunk 4 skipped"):
        assert p.result() == 7
    assert notices.take() == ["truncated file recovered"]


def _killed():
    os.kill(os.getpid(), signal.SIGKILL)


def test_a_child_that_dies_is_one_line(fork_on):
    with forked.started(_killed, what="reading x.mcap") as p, pytest.raises(forked.ChildDied) as err:
        p.result()
    assert str(err.value) == "the process reading x.mcap ended without a result (signal SIGKILL)"


def _killed_while_sending():
    return b"x" * (1 << 22)  # more than the pipe holds: the child is still writing when killed


def test_a_result_cut_short_is_one_line(fork_on, monkeypatch):
    real = forked.Pending._read

    def read_then_kill(self):
        head = os.read(self._fd, 1000)
        os.kill(self._pid, signal.SIGKILL)
        return head + real(self)

    monkeypatch.setattr(forked.Pending, "_read", read_then_kill)
    with (
        forked.started(_killed_while_sending, what="reading y.mcap") as p,
        pytest.raises(forked.ChildDied) as err,
    ):
        p.result()
    assert str(err.value) == "the process reading y.mcap ended without a result (signal SIGKILL)"


class _Unpicklable(Exception):
    def __reduce__(self):
        raise TypeError("no")


def _raises_unpicklable():
    raise _Unpicklable("lost in transit")


def test_an_exception_that_cannot_travel_is_sent_as_text(fork_on):
    with forked.started(_raises_unpicklable) as p, pytest.raises(forked.ChildDied, match="lost in transit"):
        p.result()


def _sleeps():
    time.sleep(60)


def test_leaving_without_the_result_stops_the_child(fork_on):
    t0 = time.monotonic()
    with forked.started(_sleeps) as p:
        pid = p._pid
    assert time.monotonic() - t0 < 10
    with pytest.raises(ChildProcessError):  # reaped: no zombie left
        os.waitpid(pid, os.WNOHANG)


def _records(seen):
    seen.append(os.getpid())
    return len(seen)


def test_in_process_outside_a_command_and_when_switched_off(monkeypatch):
    seen: list[int] = []
    p = forked.started(_records, seen)  # not inside allowed(): a library caller
    assert not p.forked and seen == []  # runs on result(), in this process
    assert p.result() == 1 and seen == [os.getpid()]
    monkeypatch.setenv(forked.ENV_SWITCH, "0")
    with forked.allowed():
        p = forked.started(_records, seen)
        assert not p.forked
        assert p.result() == 2


def test_nothing_is_forked_when_the_caller_has_nothing_to_do(fork_on):
    seen: list[int] = []
    p = forked.started(_records, seen, meanwhile=False)
    assert not p.forked and p.result() == 1 and seen == [os.getpid()]


def test_in_process_errors_are_raised_by_result():
    p = forked.started(_fails)
    with pytest.raises(InputError, match="hold 3"):
        p.result()
