"""Gyro calibration: bias from holds, scale and misalignment from rotations between them."""
