"""core: units, errors, rotations, kinematics, pose protocols, time-series helpers and the in-memory session types. Imports nothing else from accellog."""
