"""The door of every importer (CSV, ROS 2): stamps and samples checked as they are read, gaps counted.

``check_increasing`` (duplicated or backward stamps) and ``check_samples`` (non-finite or absurd
accelerations and rates) refuse with one line naming the sample by the importer's own label
(file:line, or topic and message index); ``GapEvents`` counts the gaps in the stamps into the file
as the recorder counts its own. The units of a text log: ``csv_checks``.
"""

from __future__ import annotations

import numpy as np

from accellog.core.errors import InputError
from accellog.core.plausible import MAX_ACCEL_G, MAX_GYRO_DPS
from accellog.core.session import Event


def check_increasing(t_s: np.ndarray, where_of, prev: float | None = None) -> None:
    """Refuse the first time stamp t_s[i] (s) that does not exceed the one before it (prev: the last
    stamp of the previous block): InputError at where_of(i) naming both times."""
    d = np.diff(t_s) if prev is None else np.diff(t_s, prepend=prev)
    bad = np.flatnonzero(~(d > 0))
    if not bad.size:
        return
    i = int(bad[0]) + (1 if prev is None else 0)
    before = float(t_s[i - 1]) if i > 0 else prev
    if t_s[i] == before:
        raise InputError(f"duplicated timestamp ({before:.9g} s, as the sample before)", where=where_of(i))
    raise InputError(f"time goes backwards ({before:.9g} s -> {t_s[i]:.9g} s)", where=where_of(i))


def check_samples(accel_g: np.ndarray, gyro_dps: np.ndarray | None, where_of) -> None:
    """Refuse the first sample whose acceleration (g) or rate (deg/s) is not finite or beyond any
    MEMS range (MAX_ACCEL_G, MAX_GYRO_DPS on an axis): InputError at where_of(i)."""
    for name, x, lim, unit in (
        ("acceleration", accel_g, MAX_ACCEL_G, "g"),
        ("rate", gyro_dps, MAX_GYRO_DPS, "deg/s"),
    ):
        if x is None:
            continue
        bad = np.flatnonzero(~(np.abs(x) <= lim).all(axis=1))
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"{name} {np.array2string(x[i], precision=4)} {unit} is not finite or beyond any MEMS "
                f"range (|{unit}| <= {lim:g}): a corrupt value?",
                where=where_of(i),
            )


GAP_PERIODS = 5.0
"""A time step longer than this many sample periods (the median step) is a gap."""


class GapEvents:
    """The gaps of an imported stream, counted as the recorder counts its own: a step longer than
    GAP_PERIODS median periods is an Event('gap') at the sample after it (its index among the
    imported samples), lost_samples = round(step / period) - 1, estimated (the stream has no sample
    counter). Fed block by block; the period is the median step of the first block."""

    def __init__(self) -> None:
        self.period_s: float | None = None
        self.prev: float | None = None
        self.n = 0
        self.events: list[Event] = []

    def add(self, t_s: np.ndarray) -> None:
        """The next stamps (s, increasing: check_increasing first)."""
        t = np.asarray(t_s, np.float64)
        if t.size:
            d = np.diff(t) if self.prev is None else np.diff(t, prepend=self.prev)
            if self.period_s is None and d.size:
                self.period_s = float(np.median(d))
            if self.period_s:
                off = 1 if self.prev is None else 0
                for j in np.flatnonzero(d > GAP_PERIODS * self.period_s).tolist():
                    lost = max(round(float(d[j]) / self.period_s) - 1, 1)
                    detail = (
                        f"{float(d[j]):.6g} s without samples (~{lost} at the median period "
                        f"{self.period_s:.6g} s; in the imported stamps)"
                    )
                    self.events.append(Event(float(t[j + off]), "gap", detail, self.n + j + off, lost))
            self.prev = float(t[-1])
        self.n += t.size
