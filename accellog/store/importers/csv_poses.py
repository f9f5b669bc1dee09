"""Pose labels of a generic CSV, collected block by block: consecutive rows with one 'pose' name form a
hold; its up vector comes from true_x,true_y,true_z (constant within the hold) or from the name
('+x'..'-z', '+z@90'), its orientation from qw,qx,qy,qz or from the name.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.protocol import pose_spec
from accellog.core.session import PoseLabel, quat4, vec3


@dataclass
class _Run:
    name: str
    start_s: float
    where: str
    up: np.ndarray | None = None
    q: np.ndarray | None = None


class PoseRuns:
    """Feed blocks in order (``feed``), then ``finish``; ``poses`` holds the labelled holds."""

    def __init__(self, path) -> None:
        self.path = path
        self.poses: list[PoseLabel] = []
        self._run: _Run | None = None
        self._name = None  # name of the last row seen ('' = unlabelled)

    def feed(self, names: np.ndarray, t_s: np.ndarray, true, quat, line_of) -> None:
        """names (n,) str of one block, t_s (n,), true (n,3) | None, quat (n,4) | None; line_of(row) -> line."""
        names = np.asarray([("" if v is None else str(v).strip()) for v in names], dtype=object)
        n = names.shape[0]
        if n == 0:
            return
        starts = np.flatnonzero(names[1:] != names[:-1]) + 1
        if names[0] != self._name:
            starts = np.concatenate([[0], starts])
        cuts = np.concatenate([[0], starts, [n]])
        cuts = np.unique(cuts)
        for s, e in zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True):
            if names[s] != self._name:
                self._close(float(t_s[s]))
                self._name = names[s]
                if self._name:
                    self._run = _Run(self._name, float(t_s[s]), f"{self.path}:{line_of(s)}")
            if self._run is not None:
                self._check(self._run, s, e, true, quat, line_of)

    def _check(self, run: _Run, s: int, e: int, true, quat, line_of) -> None:
        if true is not None:
            seg = true[s:e]
            ok = np.all(np.isfinite(seg), axis=1)
            if ok.any():
                if run.up is None:
                    run.up = seg[ok][0]
                diff = np.flatnonzero(ok & np.any(np.abs(seg - run.up) > 1e-9, axis=1))
                if diff.size:
                    raise InputError(
                        f"pose {run.name!r}: true_x,true_y,true_z change within the hold",
                        where=f"{self.path}:{line_of(s + int(diff[0]))}",
                    )
        if quat is not None and run.q is None:
            qs = quat[s:e]
            okq = np.all(np.isfinite(qs), axis=1)
            if okq.any():
                run.q = qs[okq][0]

    def _close(self, end_s: float) -> None:
        run, self._run = self._run, None
        if run is None:
            return
        spec = None
        with contextlib.suppress(InputError):  # unknown names need true_x,true_y,true_z
            spec = pose_spec(run.name, 0.0)
        if run.up is not None:
            if abs(float(np.linalg.norm(run.up)) - 1.0) > 1e-3:
                raise InputError(
                    f"pose {run.name!r}: true_x,true_y,true_z = {run.up.tolist()} is not a unit vector",
                    where=run.where,
                )
            up = vec3(run.up)
        elif spec is None:
            raise InputError(
                f"unknown pose {run.name!r} without true_x,true_y,true_z: use +x,-x,+y,-y,+z,-z "
                "(optionally '@<deg>') or give the up vector",
                where=run.where,
            )
        else:
            up = spec.up_sensor
        q = None
        if run.q is not None:
            if abs(float(np.linalg.norm(run.q)) - 1.0) > 1e-3:
                raise InputError(
                    f"pose {run.name!r}: qw,qx,qy,qz = {run.q.tolist()} is not a unit quaternion",
                    where=run.where,
                )
            q = quat4(run.q)
        if q is None and spec is not None and np.allclose(spec.up_sensor, up, atol=1e-9):
            q = spec.q_sensor_to_world
        self.poses.append(PoseLabel(run.name, run.start_s, float(end_s), up, q, len(self.poses)))

    def finish(self, end_s: float) -> list[PoseLabel]:
        """Close the last hold at end_s (last time + one median interval) and return the poses."""
        self._close(end_s)
        return self.poses
