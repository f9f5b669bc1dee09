"""Fleet inputs (issue 27 item 5): a session glob follows each real file once (symlink loops and
links to the same file do not multiply sessions), and names read from file metadata (a serial
'..') never become path parts that leave FLEET/cal/."""

from __future__ import annotations

import glob
import os
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.flows.fleet_inputs import MAX_PART, find_sessions, safe_part, unique_files

REPO = Path(__file__).resolve().parents[2]


def _tree(root: Path) -> list[Path]:
    """root/{a/s1.mcap, a/deep/s2.mcap, b/s3.mcap, b/notes.txt, .hidden/h.mcap}; returns the 3 sessions."""
    files = [root / "a" / "s1.mcap", root / "a" / "deep" / "s2.mcap", root / "b" / "s3.mcap"]
    for f in [*files, root / "b" / "notes.txt", root / ".hidden" / "h.mcap"]:
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_bytes(b"x")
    return files


def test_symlink_loops_and_duplicate_links_give_each_real_file_once(tmp_path):
    root = tmp_path / "S"
    files = _tree(root)
    (root / "a" / "deep" / "up").symlink_to(root)  # a loop back to the top
    pattern = str(root / "**" / "*.mcap")
    assert len(glob.glob(pattern, recursive=True)) > 3 * 10  # what Python's glob makes of one loop
    (root / "b" / "loop2").symlink_to(root / "a")  # a second loop: glob's walk would grow exponentially
    (root / "b" / "again.mcap").symlink_to(root / "a" / "s1.mcap")  # a second name for one file
    (root / "c").symlink_to(root / "b")  # a second name for a whole folder
    found = find_sessions(pattern)
    assert found == sorted(str(f) for f in files)
    assert len({os.path.realpath(p) for p in found}) == len(found) == 3


@pytest.mark.parametrize(
    "rel",
    ["**/*.mcap", "*/*.mcap", "a/**/*.mcap", "**/deep/*.mcap", "**", "*/s[13].mcap", "b/*", "**/*.txt"],
)
def test_same_matches_as_glob_on_a_tree_without_links(tmp_path, monkeypatch, rel):
    root = tmp_path / "S"
    _tree(root)
    want = sorted(p for p in glob.glob(str(root / rel), recursive=True) if os.path.isfile(p))
    assert find_sessions(str(root / rel)) == want
    monkeypatch.chdir(root)  # a relative pattern gives relative paths, as glob does
    want_rel = sorted(p for p in glob.glob(rel, recursive=True) if os.path.isfile(p))
    assert find_sessions(rel) == want_rel


def test_a_list_of_sessions_keeps_each_real_file_once(tmp_path):
    files = _tree(tmp_path / "S")
    (tmp_path / "link.mcap").symlink_to(files[1])
    given = [files[2], tmp_path / "link.mcap", files[0], files[1], str(files[2])]
    assert unique_files(given) == [str(files[2]), str(tmp_path / "link.mcap"), str(files[0])]


def test_no_match_is_one_input_error(tmp_path):
    with pytest.raises(InputError, match="no session file matches"):
        find_sessions(str(tmp_path / "**" / "*.mcap"))


@pytest.mark.parametrize(
    "name",
    ["..", ".", "", "../../etc", "/etc/passwd", "a/../../b", ".hidden", "x" * 300, "IMU\x00-1", "..\\.."],
)
def test_safe_part_is_one_component_inside_its_folder(tmp_path, name):
    part = safe_part(name)
    assert part and not part.startswith(".") and "/" not in part and "\x00" not in part
    assert len(part) <= MAX_PART
    assert (tmp_path / part).resolve().parent == tmp_path.resolve()


def test_safe_part_keeps_ordinary_names_and_separates_dot_names():
    assert safe_part("IMU-0001") == "IMU-0001"
    assert safe_part("host/i2c-1/0x68") == "host_i2c-1_0x68"  # the layout of earlier fleet folders
    assert safe_part(None) == safe_part("") == "unknown"
    assert (
        len({safe_part("."), safe_part(".."), safe_part("..."), safe_part("x" * 300), safe_part("x" * 301)})
        == 5
    )


def test_fleet_run_with_serial_dot_dot_writes_inside_fleet_cal(tmp_path, capsys):
    """One fast CLI run (--workers 0): a session whose metadata serial is '..'."""
    from accellog.flows.simulate import Scenario, simulate

    sessions = tmp_path / "sessions" / "one"
    sessions.mkdir(parents=True)
    sc = Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=100.0, chip_seed=5, seed=6)
    sc.validate()
    simulate(sc, sessions / "s.mcap", serial="..")
    (sessions / "loop").symlink_to(tmp_path / "sessions")
    out = tmp_path / "FLEET"
    pattern = str(tmp_path / "sessions" / "**" / "*.mcap")
    rc = main(
        ["fleet", "run", str(REPO / "pipelines" / "fleet.toml"), pattern, "-o", str(out), "--workers", "0"]
    )
    assert rc == 0, capsys.readouterr().err
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*.json") if "sessions" not in p.parts)
    assert len(written) == 1 and written[0].parts[:3] == ("FLEET", "cal", safe_part(".."))
    from accellog.flows.fleet import read_table

    rows = read_table(out / "fleet.parquet")
    assert len(rows) == 1 and rows[0]["device"] == ".." and not rows[0]["error"]  # the table keeps the name


@settings(max_examples=300, deadline=None)
@given(name=st.text(max_size=200))
def test_safe_part_property_any_text(name):
    """Whatever a file's metadata holds, its path part is one component that stays in its folder."""
    part = safe_part(name)
    assert part and part == safe_part(name) and len(part) <= MAX_PART
    assert os.sep not in part and "\x00" not in part and not part.startswith(".")
    assert os.path.normpath(os.path.join("FLEET", "cal", part)) == os.path.join("FLEET", "cal", part)


def test_byte_identical_copies_in_several_folders_share_their_calibration_file(tmp_path, capsys):
    """Copies of one session (a backup beside the original) map to one calibration file name: the
    two workers write it in turn (each waits on the file's lock), the run ends with its table."""
    import shutil

    from accellog.flows.fleet import read_table
    from accellog.flows.simulate import Scenario, simulate

    first = tmp_path / "sessions" / "c0" / "s.mcap"
    first.parent.mkdir(parents=True)
    sc = Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=100.0, chip_seed=5, seed=6)
    sc.validate()
    simulate(sc, first)
    for k in range(1, 8):
        (tmp_path / "sessions" / f"c{k}").mkdir()
        shutil.copyfile(first, tmp_path / "sessions" / f"c{k}" / "s.mcap")
    out = tmp_path / "FLEET"
    pattern = str(tmp_path / "sessions" / "**" / "*.mcap")
    rc = main(
        ["fleet", "run", str(REPO / "pipelines" / "fleet.toml"), pattern, "-o", str(out), "--workers", "2"]
    )
    assert rc == 0, capsys.readouterr().err
    rows = read_table(out / "fleet.parquet")
    assert len(rows) == 8 and not any(r["error"] for r in rows)
    assert len({r["calibration"] for r in rows}) == 1 and (out / rows[0]["calibration"]).is_file()


def test_two_workers_storing_two_names_in_opposite_orders_both_finish(tmp_path):
    """Worker A holds calibration name x and needs y while worker B holds y and needs x (copies of two
    sessions whose folders sort them in opposite orders): the one that finds its next name locked
    commits what it holds before it waits, so neither waits for the other for ever."""
    import threading

    from accellog.flows.fleet_table import stage_result
    from accellog.store.atomic import commit_all

    def result(name: str) -> dict:
        row = {"device": "IMU-1", "session_name": name, "content_sha256": "ab" * 32, "model": "model3"}
        return {"rows": [row], "cals": {"model3": {"session": name}}}

    both_hold_one = threading.Barrier(2, timeout=10)
    done: list[list[str]] = []

    def worker(order: tuple[str, str]) -> None:
        staged: dict = {}
        rows = stage_result(tmp_path, result(order[0]), staged)
        both_hold_one.wait()
        rows += stage_result(tmp_path, result(order[1]), staged)
        commit_all(list(staged.values()))
        done.append([r["calibration"] for r in rows])

    threads = [threading.Thread(target=worker, args=(o,), daemon=True) for o in (("x", "y"), ("y", "x"))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=20)
    assert not any(t.is_alive() for t in threads), "the two writers wait for each other"
    assert len(done) == 2
    names = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert names == ["cal/IMU-1/x_abababab_model3.json", "cal/IMU-1/y_abababab_model3.json"]
