"""Simulated read speed of driver + emulated chip, as a multiple of real time (goal >= 100x).

A 1 kHz session (six-pose protocol, datasheet errors and noise) is read with ``Mpu9250.read`` in a
loop while a SimClock advances ``poll_s`` per read (the FIFO holds 36 packets = 36 ms). Variants,
measured side by side in one run: direct bus object, plus magnetometer reads, through the real
smbus2.SMBus (emulated i2c-dev ioctls), and 28-byte SMBus block reads instead of i2c_rdwr.

    python benchmarks/bench_emulator.py [--session-s 120]
"""

from __future__ import annotations

import argparse
import contextlib
import time

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.emulator.i2c_dev import emulated_i2c_bus
from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.core.protocol import six_position


def run(session_s: float, poll_s: float, *, mag: bool = False, smbus: bool = False, rdwr: bool = True):
    clock = SimClock()
    model = SensorModel(
        PoseSequenceMotion(six_position(30.0)), AccelErrors.datasheet(7), GyroErrors.datasheet(7), seed=1
    )
    chip = EmulatedMpu9250(model, clock, support_i2c_rdwr=rdwr)
    ctx = emulated_i2c_bus(chip, 1) if smbus else contextlib.nullcontext()
    with ctx:
        if smbus:
            from smbus2 import SMBus

            bus = SMBus(1)
        else:
            bus = chip
        drv = Mpu9250(bus, clock_ns=clock.now_ns)
        drv.configure()
        if mag:
            drv.enable_magnetometer()
        drv.start()
        n_reads = round(session_s / poll_s)
        samples = 0
        t0 = time.perf_counter()
        for _ in range(n_reads):
            clock.sleep(poll_s)
            samples += drv.read().n
            if mag:
                drv.read_mag()
        wall = time.perf_counter() - t0
        if smbus:
            bus.close()
    return samples, wall, n_reads


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session-s", type=float, default=120.0, help="simulated session length per variant (s)")
    args = ap.parse_args()
    variants = [
        ("driver + chip, 25 ms reads", dict(poll_s=0.025)),
        ("driver + chip, 10 ms reads", dict(poll_s=0.010)),
        ("+ magnetometer read each poll", dict(poll_s=0.025, mag=True)),
        ("real smbus2.SMBus (ioctl emulation)", dict(poll_s=0.025, smbus=True)),
        ("SMBus 28-byte block fallback", dict(poll_s=0.025, rdwr=False)),
    ]
    print(f"1 kHz session, {args.session_s:g} s simulated per variant")
    print(f"{'variant':40s} {'samples':>8s} {'wall s':>7s} {'us/read':>8s} {'x real time':>12s}")
    for name, kw in variants:
        samples, wall, reads = run(args.session_s, **kw)
        print(f"{name:40s} {samples:8d} {wall:7.3f} {wall / reads * 1e6:8.1f} {args.session_s / wall:12.0f}")


if __name__ == "__main__":
    main()
