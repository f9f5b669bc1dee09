"""Helper processes a command line will need, started from its raw words before typer and the
command's modules are imported, so that their own imports run beside the command's instead of
beside its computation (each measured end to end, interleaved runs on 2 cores):

- the .rrd writer child (``present.rrd.offload_process``) of RRD_CHILD_COMMANDS with ``--rrd``:
  ``replay --rrd`` 1 h 1.26-1.30x -> 1.17x the replay alone (started after parsing before);
- the fork server of local fleet workers (``flows.fleet_dask.prestart_workers``) of ``fleet run``
  without ``--scheduler``, ``--workers 0`` or an up-to-date table (without ``--force``): 300 sessions
  on 2 workers 4.76-5.34 s -> 4.57-4.80 s, 1.52-1.55x -> 1.62-1.69x the serial loop (two runs of 5).

Only the standard library and these two light modules are imported here. A command that then fails
stops the writer child (``accellog.cli.main``); a fork server nobody used exits once its imports end.
"""

from __future__ import annotations

import os

RRD_CHILD_COMMANDS = ("fit", "evaluate", "drift", "run", "track", "replay", "compare")
"""The commands whose --rrd file is written by a child process (present.rrd.offload), measured to
gain; the others (diagnose, demo, doctor, magcal, noise, workbench, fleet) write it themselves."""


def option(args: list[str], *names: str) -> str | None:
    """The value of the last of the options ``names`` in args ('--name value' or '--name=value'),
    None when absent."""
    found = None
    for i, a in enumerate(args):
        for name in names:
            if a == name and i + 1 < len(args):
                found = args[i + 1]
            elif a.startswith(name + "="):
                found = a[len(name) + 1 :]
    return found


def start_helpers(args: list[str]) -> None:
    """Start what the command line args will need (module docstring); nothing for --help."""
    if not args or "--help" in args:
        return
    if args[0] in RRD_CHILD_COMMANDS and option(args, "--rrd") is not None:
        from accellog.present.rrd.offload_process import prestart

        prestart()
    elif args[:2] == ["fleet", "run"] and _local_fleet_computes(args):
        from accellog.flows.fleet_dask import prestart_workers

        prestart_workers()


def _local_fleet_computes(args: list[str]) -> bool:
    """Whether ``fleet run`` args start a local cluster that will have sessions to run."""
    if option(args, "--scheduler") is not None or option(args, "--workers") == "0":
        return False
    from accellog.flows.fleet_table import TABLE_NAME

    out = option(args, "-o", "--out")
    return "--force" in args or out is None or not os.path.exists(os.path.join(out, TABLE_NAME))
