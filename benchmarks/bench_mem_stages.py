"""Peak memory per stage of the fit side on one session file (where the peak is, 4 h vs 24 h).

    python benchmarks/bench_mem_stages.py MODE SESSION.mcap

MODE: `observe` (segment.observations of the file alone), `stream` (observations, fit model3, diagnose:
bench_scale's `stream`) or `fit` (the fit command's stages: the observation pass, the model3 fit, the gyro
calibration). After each stage: the peak resident size of that stage (VmHWM, reset between stages
through /proc/self/clear_refs), the resident size held after it (VmRSS; RssAnon / RssFile: the
heap and the mapped file) and its CPU time. BLAS on one thread. Linux only (/proc).
"""

from __future__ import annotations

import sys
import time

import numpy  # noqa: F401  (first: threadpoolctl limits only the BLAS libraries already loaded)
from threadpoolctl import threadpool_limits

threadpool_limits(1, "blas")


def _status() -> dict[str, float]:
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            key, val = line.split(":", 1)
            if key in ("VmHWM", "VmRSS", "RssAnon", "RssFile"):
                out[key] = int(val.split()[0]) / 1024
    return out


class _Stages:
    def __init__(self) -> None:
        self.t0 = time.process_time()

    def mark(self, name: str) -> None:
        s, cpu = _status(), time.process_time() - self.t0
        print(
            f"{name:>14}: peak {s['VmHWM']:6.0f} MB  held {s['VmRSS']:6.0f} MB (heap {s['RssAnon']:.0f}, "
            f"file {s['RssFile']:.0f})  CPU {cpu:6.2f} s",
            flush=True,
        )
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")  # reset VmHWM: the next mark is that stage's own peak
        self.t0 = time.process_time()


def main(mode: str, path: str) -> None:
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.observe.segment import observations

    st = _Stages()
    if mode == "fit":
        from accellog.flows import stages

        st.mark("imports")
        from accellog.calibrate.gyro.calibrate import calibrate_source, first_pass_of, temp_order_of
        from accellog.calibrate.observe.segment import observe_riding
        from accellog.store.source import open_source

        obs, first, src = observe_riding(open_source(path), rider=first_pass_of)
        st.mark("observations")
        out = stages.run_fit(src, obs=obs, gyro=False)  # the fit reuses the table just read
        out.fit.release_jacobian()  # as run_fit does before the gyro passes
        st.mark("fit model3")
        calibrate_source(src, temp_order=temp_order_of(out.fit.model.terms), first=first)
        st.mark("gyro")
        return
    from accellog.calibrate.diagnosis.diagnose import diagnose
    from accellog.calibrate.model.fit import fit_model

    st.mark("imports")
    obs = observations(path)
    st.mark("observations")
    if mode == "stream":
        fit_model(obs, build_model("model3"))
        st.mark("fit model3")
        diagnose(obs, build_model("model3"))
        st.mark("diagnose")
    print(f"{obs.n} observation rows")


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("observe", "stream", "fit"):
        raise SystemExit(__doc__.strip().splitlines()[2].strip())
    main(sys.argv[1], sys.argv[2])
