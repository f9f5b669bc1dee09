"""What a fleet worker process imports before its first task (preloaded by the local cluster's fork
server, imported by ``fleet.warm_worker`` elsewhere)."""

import scipy.optimize  # noqa: F401

import accellog.calibrate.diagnosis.diagnose
import accellog.calibrate.gyro.calibrate
import accellog.calibrate.model.fit
import accellog.calibrate.model.variance
import accellog.flows.fleet
import accellog.flows.pipeline
import accellog.store.reader  # noqa: F401
