"""Magnetometer hard and soft iron."""
