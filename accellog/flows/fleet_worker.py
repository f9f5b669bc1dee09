"""What a local fleet worker needs, imported once by the fork server its processes are forked from.

``fleet_dask.prestart_workers`` starts multiprocessing's fork server with this module preloaded when
``accellog fleet run`` will start a LocalCluster: the server imports dask.distributed's worker side,
numpy, scipy.optimize and the pipeline's code (~1.2 s of CPU) while the command imports and lists
the sessions, and every worker is then forked from it ready to run, instead of each spawned worker
importing all of it on the cores the sessions need (figures: docs/fleet.md). glibc's malloc
thresholds of ``fleet_dask.WORKER_CONFIG`` (environment variables read when a process starts, which
a forked worker does not do) are set here with ``mallopt`` and inherited by every fork.
"""

from __future__ import annotations

import distributed.nanny
import distributed.worker  # noqa: F401

from accellog.core.heap import set_malloc_thresholds
from accellog.flows.fleet import warm_worker
from accellog.flows.fleet_dask import MALLOC_MMAP_THRESHOLD, MALLOC_TRIM_THRESHOLD

set_malloc_thresholds(MALLOC_TRIM_THRESHOLD, MALLOC_MMAP_THRESHOLD)
warm_worker()
