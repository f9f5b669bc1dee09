"""Fleet inputs: the session files a glob names (each real file once, symlink loops cut) and safe path
parts made from names found in file metadata (device ids, serials, session names).

``find_sessions`` walks the tree itself instead of ``glob.glob(recursive=True)``: Python's ``**``
follows directory symlinks without remembering where it has been, so one loop turns 3 files into
120 paths (and two loops into an exponential walk). Here every directory is entered once (by device
and inode), and files reached by several paths are kept once (by ``os.path.realpath``), under the
first path in sorted order.
"""

from __future__ import annotations

import fnmatch
import glob
import hashlib
import os
import re

from accellog.core.errors import InputError

_UNSAFE = re.compile(r"[^A-Za-z0-9_.:-]+")
MAX_PART = 80
"""Longest path part kept as it is (characters); longer names are cut and suffixed with a hash."""


def safe_part(name: str | None) -> str:
    """A single path component from a name read out of a file (never '', '.', '..', hidden or a path).

    Characters outside [A-Za-z0-9_.:-] become '_'; a name that is then empty, starts with '.' or is
    longer than MAX_PART becomes its cleaned, shortened form + '-' + the first 8 hex digits of the
    SHA-256 of the original name (so '..' and '.' stay distinct and never climb out of the folder)."""
    raw = name or "unknown"
    s = _UNSAFE.sub("_", raw)
    if s.startswith(".") or len(s) > MAX_PART:
        digest = hashlib.sha256(raw.encode("utf-8", "surrogatepass")).hexdigest()[:8]
        s = f"{(s.lstrip('.') or 'id')[: MAX_PART - 9]}-{digest}"
    return s


def find_sessions(pattern: str) -> list[str]:
    """Sorted files matching a glob ('**' = any number of folders), each real file once; InputError
    when none match. Directory symlinks are followed, but every directory is entered only once."""
    pattern = os.path.expanduser(pattern)
    if "**" not in pattern:
        found = sorted(p for p in glob.glob(pattern) if os.path.isfile(p))
    else:
        found = _walk_glob(pattern)
    files = unique_files(found)
    if not files:
        raise InputError("no session file matches", where=pattern)
    return files


def unique_files(paths) -> list[str]:
    """``paths`` in their order, each real file (``os.path.realpath``) once, under its first name."""
    files, seen = [], set()
    for p in map(str, paths):
        real = os.path.realpath(p)
        if real not in seen:
            seen.add(real)
            files.append(p)
    return files


def _walk_glob(pattern: str) -> list[str]:
    """Files under the pattern's fixed root matching its remaining parts (segment by segment)."""
    parts = pattern.split(os.sep)
    k = next(i for i, s in enumerate(parts) if glob.has_magic(s))
    root = os.sep.join(parts[:k]) or ("." if not pattern.startswith(os.sep) else os.sep)
    rest = [s for s in parts[k:] if s]
    out: list[str] = []
    visited: set[tuple[int, int]] = set()
    for top, dirs, names in os.walk(root, followlinks=True):
        try:
            st = os.stat(top)
        except OSError:  # vanished or unreadable while walking: nothing to take from it
            dirs[:] = []
            continue
        if (st.st_dev, st.st_ino) in visited:
            dirs[:] = []
            continue
        visited.add((st.st_dev, st.st_ino))
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        rel = os.path.relpath(top, root)
        segs = [] if rel == "." else rel.split(os.sep)
        for n in names:
            if _match([*segs, n], rest):
                out.append(os.path.join(top, n) if parts[:k] else os.path.join(rel, n) if segs else n)
    return sorted(p for p in out if os.path.isfile(p))


def _match(segs: list[str], pat: list[str]) -> bool:
    """glob semantics per path segment: '**' matches zero or more folders; '*' never matches a
    leading '.' unless the pattern segment starts with one."""
    if not pat:
        return not segs
    if pat[0] == "**":
        return any(_match(segs[i:], pat[1:]) for i in range(len(segs) + 1))
    if not segs:
        return False
    s, p = segs[0], pat[0]
    if s.startswith(".") and not p.startswith("."):
        return False
    return fnmatch.fnmatchcase(s, p) and _match(segs[1:], pat[1:])
