"""Emulated MPU-9250: register-level chip, physical sensor model, truth motions, clocks.

Modules: ``chip`` (EmulatedMpu9250, smbus2 method surface), ``sensor_model`` (AccelErrors,
GyroErrors, SensorModel), ``poses`` (PoseSequenceMotion), ``temperature`` (TemperaturePath),
``clock`` (SimClock, RealClock), ``i2c_dev`` (emulated_i2c_bus: the real smbus2.SMBus talks to the
emulator), ``robot`` (a driving robot motion). Import the submodules directly; nothing is loaded here.
"""
