"""acquire: the MPU-9250 registers, the smbus2 driver, stillness detection, the guided recorder and the register-level emulator. Imports core."""
