"""The door for paths on the command line: every output option of every command checked against
every input, once, before the command runs.

An output option (``OUTPUT_OPTIONS``: ``-o``, ``--rrd``, ``--ros2``, ``--output-dir``,
``--screenshot``, ...) is refused with one line when it exists and is not what the command writes
(a device such as /dev/null, a FIFO, a socket; a directory where a file goes, a file where a folder
goes) or when it is the same file as any input of the command (every other path argument), by
identity after resolving links (``accellog.store.atomic.refuse_inputs``). While the command runs,
its inputs stay declared (``declared_inputs``): every file it writes, also inside an output folder,
is checked against them again.

A file output also needs its folder (no folder is created: a missing one is refused, naming it), and
the file of ``-o`` (``REPLACED_ONLY_WITH_FORCE``) of a command with ``--force`` is not replaced
without it (``accellog.store.atomic.check_output``, as every importer checks its output).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from accellog.core.errors import InputError
from accellog.store.atomic import check_output, refuse_inputs, same_file, special_kind

FILE, FOLDER, EITHER = "file", "folder", "file or folder"

OUTPUT_OPTIONS = {
    "output": FILE,
    "out": FILE,
    "rrd": FILE,
    "screenshot": FILE,
    "ros2": EITHER,  # OUT.mcap or a bag folder
    "output_dir": FOLDER,
}
REPLACED_ONLY_WITH_FORCE = ("output", "out")
"""The -o options: an existing file is replaced only with --force (when the command has one)."""
OUTPUT_KINDS = {  # (command's function, parameter) whose output is not OUTPUT_OPTIONS' kind
    ("accellog.cli.demo.demo", "out"): FOLDER,
    ("accellog.cli.fleet.run", "out"): FOLDER,
    ("accellog.cli.record.simulate", "out"): EITHER,  # a folder with --fleet
}


def _paths(value: Any) -> Iterator[Path]:
    if isinstance(value, Path):
        yield value
    elif isinstance(value, (list, tuple)):
        for v in value:
            yield from _paths(v)


def check_paths(command: str, names: dict[str, str], kwargs: dict[str, Any]) -> list[Path]:
    """Refuse (InputError naming the option) an output of `command` (its function, module.name)
    that exists and is not what it writes, or that is one of its inputs; returns the inputs.
    names: parameter -> option spelling."""
    outs = {k: v for k, v in kwargs.items() if k in OUTPUT_OPTIONS and isinstance(v, Path)}
    inputs = [p for k, v in kwargs.items() if k not in outs for p in _paths(v)]
    seen: list[Path] = []
    for name, out in outs.items():
        kind = OUTPUT_KINDS.get((command, name), OUTPUT_OPTIONS[name])
        what = names.get(name, name)
        found = special_kind(out)
        if found == "a directory" and kind == FILE:
            raise InputError(f"{what} is a directory; give a file name", where=str(out))
        if found not in (None, "a directory"):
            raise InputError(f"{what} is {found}, not a regular file; give another name", where=str(out))
        if kind == FOLDER and out.exists() and found is None:
            raise InputError(f"{what} is an existing file, not a folder", where=str(out))
        refuse_inputs(out, inputs, what)
        if kind == FILE:
            replace = name not in REPLACED_ONLY_WITH_FORCE or kwargs.get("force", True) is not False
            check_output(out, inputs, overwrite=replace, what=what)
        for other in seen:
            if same_file(out, other):
                raise InputError(f"two outputs are the same file ({other})", where=str(out))
        seen.append(out)
    return inputs
