"""One behaviour for every command (issue 45, item 8): an existing -o file is replaced only with
--force (the check every importer makes), a missing output folder is refused and not created, the
exit codes are the README's, `export --to` offers its targets, and usage lines name arguments as
click does (SESSION, not {session})."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from accellog.cli import INTERRUPTED, main
from accellog.cli.app import COMMANDS, LazyGroup, _click, command_group
from accellog.core.errors import AccellogError, DeviceError, InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.present.export_targets import TARGETS

README = Path(__file__).resolve().parents[2] / "README.md"


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    p = tmp_path_factory.mktemp("six") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=2), p)
    return p


def test_an_existing_output_is_replaced_only_with_force(session, tmp_path, capsys):
    cal = tmp_path / "cal.json"
    cal.write_text("keep me")
    rc, _, err = _run(["fit", session, "-o", cal], capsys)
    assert rc == 2 and err.strip() == f"accellog: error: {cal}: file exists; use --force to replace it"
    assert cal.read_text() == "keep me"
    assert _run(["fit", session, "-o", cal, "--force"], capsys)[0] == 0
    assert cal.read_text() != "keep me"
    ros = tmp_path / "ros.yaml"  # export, another module's command, behaves the same
    ros.write_text("keep me")
    rc, _, err = _run(["export", cal, "--to", "ros", "-o", ros], capsys)
    assert rc == 2 and "use --force" in err and ros.read_text() == "keep me"
    assert _run(["export", cal, "--to", "ros", "-o", ros, "--force"], capsys)[0] == 0


@pytest.mark.parametrize("option", ["-o", "--rrd"])
def test_a_missing_output_folder_is_refused_not_created(session, tmp_path, capsys, option):
    missing = tmp_path / "no" / "such"
    argv = ["fit", session, "-o", tmp_path / "cal.json", option, missing / "out.x"]
    if option == "-o":
        argv = ["fit", session, "-o", missing / "cal.json"]
    rc, _, err = _run(argv, capsys)
    assert rc == 2 and err.strip() == f"accellog: error: {missing}: folder does not exist"
    assert not (tmp_path / "no").exists()


def test_exit_codes_are_the_readmes():
    rows = re.findall(r"^\| (\d+) \| (.+) \|$", README.read_text(), re.M)
    codes = {int(c): text for c, text in rows}
    assert set(codes) == {0, 1, 2, 3, 130}
    assert AccellogError.exit_code == InputError.exit_code == 2 and "bad input" in codes[2]
    assert DeviceError.exit_code == 3 and "device" in codes[3]
    assert INTERRUPTED == 130 and "interrupted" in codes[130]
    assert "doctor --strict" in codes[1]


def test_export_to_offers_its_targets(tmp_path, capsys):
    group = command_group()
    export = group.get_command(_click.Context(group), "export")
    (to,) = [p for p in export.params if p.name == "to"]
    ctx = _click.Context(export)
    assert [c.value for c in to.shell_complete(ctx, "")] == list(TARGETS)  # what <TAB> offers
    assert [c.value for c in to.shell_complete(ctx, "k")] == ["kalibr"]
    rc, _, err = _run(["export", tmp_path / "c.json", "--to", "nope"], capsys)
    assert rc == 2 and "'nope' is not one of" in err


def test_usage_lines_name_arguments_in_capitals():
    group = command_group()
    ctx = _click.Context(group, info_name="accellog")
    assert isinstance(group, LazyGroup)
    for name in COMMANDS:
        cmd = group.get_command(ctx, name)
        for sub in getattr(cmd, "commands", {"": cmd}).values():
            usage = " ".join(sub.collect_usage_pieces(_click.Context(sub, parent=ctx)))
            assert "{" not in usage and not re.search(r"\b[a-z_]+\.\.\.", usage), (name, usage)
            args = [p for p in sub.params if p.param_type_name == "argument"]
            assert all(p.metavar and p.metavar[0].isupper() for p in args), (name, usage)


def test_swapped_arguments_name_the_file_kind(session, tmp_path, capsys):
    cal = tmp_path / "cal.json"
    assert _run(["fit", session, "-o", cal], capsys)[0] == 0
    blob = tmp_path / "blob.bin"
    blob.write_bytes(bytes(range(128, 256)))
    cases = [
        (["evaluate", cal, "--cal", session], session, "this is an MCAP file (a session or a ROS 2 bag), not a calibration file"),
        (["export", session, "--to", "ros", "-o", tmp_path / "r.yaml"], session, "this is an MCAP file"),
        (["fit", cal, "-o", tmp_path / "x.json"], cal, "this is an accellog calibration (written by `accellog fit -o`), not a session"),
        (["diagnose", cal], cal, "this is an accellog calibration"),
        (["evaluate", session, "--cal", blob], blob, "not UTF-8 text, so not a calibration file"),
    ]  # fmt: skip
    for argv, named, says in cases:
        rc, _, err = _run(argv, capsys)
        assert rc == 2 and err.count("\n") == 1, (argv, err)
        assert err.startswith(f"accellog: error: {named}: ") and says in err, (argv, err)
        assert "Decode" not in err


def _leaves(group, ctx):
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        subs = getattr(cmd, "commands", None)
        if subs is None:
            yield [name], cmd
        else:
            yield from (([name, s], c) for s, c in subs.items())


def test_every_commands_help_has_an_example_that_uses_its_own_options():
    """Each command's help shows at least one `accellog ...` line (as the README says), and every
    flag of an example is one that command has (an example cannot outlive a renamed option)."""
    import shlex

    group = command_group()
    ctx = _click.Context(group, info_name="accellog")
    for path, cmd in _leaves(group, ctx):
        text = " ".join((cmd.help or "").split())
        uses = [
            u
            for span in re.findall(r"`(accellog [^`]+)`", text)
            for u in re.split(r";|>|&&", span)
            if u.strip().startswith("accellog ")
        ]
        mine = [u for u in uses if shlex.split(u)[1 : 1 + len(path)] == path]
        assert mine, f"accellog {' '.join(path)}: no example in its help"
        opts = {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)}
        for use in mine:
            flags = [w.split("=")[0] for w in shlex.split(use) if w.startswith("-")]
            assert set(flags) <= opts, (path, use, set(flags) - opts)
