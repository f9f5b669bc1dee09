"""User effect: mechanical creep after each placement, quadratic in the time since the hold began.

    a'_i += c_i t_in_pose^2        (c_i in g/s^2; t_in_pose_s: time since the pose began, s)

Load with `accellog diagnose S.mcap --model model3 --effects-file examples/effects_creep.py --add pose_creep2`.
"""

import numpy as np

from accellog import Effect, per_axis


def creep(p, f_g, drivers):
    t2 = drivers["t_in_pose_s"] ** 2
    return np.stack([p["c_x"] * t2, p["c_y"] * t2, p["c_z"] * t2], axis=1)


EFFECTS = [
    Effect(
        name="pose_creep2",
        params=per_axis("c", "g/s^2", 0.0, 1e-6),
        drivers=("t_in_pose_s",),
        meaning="fixture/mount creep after placement, growing with (time in pose)^2",
        equation="c_i t_in_pose_s^2",
        reveal="several windows per hold (long holds)",
        contribution=creep,
    )
]
