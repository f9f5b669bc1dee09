"""User effect: a bias that follows relative humidity (a made-up driver 'humidity_pct').

Load with `--effects-file examples/effects_humidity.py` (CLI) or
`build_model("model3", add=["humidity_bias"], effects_file="examples/effects_humidity.py")`;
pass the signal as drivers={"humidity_pct": array aligned with the observation rows}.
"""

import numpy as np

from accellog import Effect, per_axis


def humidity_bias(p, f_g, drivers):
    """a' += hb_i (RH - 50 %): g per %RH, per axis."""
    h = drivers["humidity_pct"] - 50.0
    return np.stack([p["hb_x"] * h, p["hb_y"] * h, p["hb_z"] * h], axis=1)


HUMIDITY = Effect(
    name="humidity_bias",
    params=per_axis("hb", "g/%RH", 0.0, 1e-4),
    drivers=("humidity_pct",),
    meaning="package swelling with moisture shifts the bias",
    equation="hb_i (RH - 50)",
    reveal="holds at different humidity levels",
    contribution=humidity_bias,
)
