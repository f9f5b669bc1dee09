"""calibrate: segmentation into holds, noise, the effect library, models, least squares, the calibration file, diagnosis and gyro calibration. Imports core and store."""
