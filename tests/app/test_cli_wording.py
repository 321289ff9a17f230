"""Command-line wording (issue 33 item 4): the top-level help, a mistyped option's suggestion."""

from __future__ import annotations

import pytest

from dropvision.app.cli import build_parser, main, suggestion


def test_top_level_help_is_written_for_users(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "exposing" not in out and "register(subparsers)" not in out  # was the module's docstring, cut
    assert "dropvision init FOLDER" in out and "dropvision measure FOLDER" in out


def test_underscore_option_gets_the_commands_usage_and_a_suggestion(capsys, tmp_path):
    with pytest.raises(SystemExit) as info:
        main(["measure", str(tmp_path), "--out", str(tmp_path / "r"), "--pixel_size_um", "3"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: dropvision measure")  # the command's usage, not the top level's
    assert "--pixel_size_um: did you mean --pixel-size-um?" in err
    assert not (tmp_path / "r").exists()


def test_suggestion_rules():
    options = [o for a in build_parser()._subparsers._group_actions[0].choices["measure"]._actions
               for o in a.option_strings if o.startswith("--")]
    assert suggestion("--pixel_size_um=3", options) == "--pixel-size-um"
    assert suggestion("--Delay_US", options) == "--delay-us"
    assert suggestion("--pixel-size-mm", options) == "--pixel-size-um"
    assert suggestion("--frobnicate", options) is None


def test_numbers_are_printed_to_meaningful_digits(tmp_path, capsys):
    """issue 33: a pixel size from the nozzle's width was printed with 16 digits (-v)."""
    import re
    import shutil
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "sample_frames" / "u55_u30"
    folder = tmp_path / "seq"
    folder.mkdir()
    for f in sorted(src.glob("f_*.png"))[::6]:
        shutil.copy(f, folder / f.name)
    # no pixel size: it comes from the nozzle's measured outer width (many digits)
    assert main(["measure", str(folder), "--out", str(tmp_path / "r"), "--nozzle-outer-diameter-um", "361",
                 "--nozzle-inner-diameter-um", "200", "-v", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "pixel_size " in out
    assert not re.search(r"\d\.\d{6,}", out), out  # at most 4-5 significant digits anywhere


def test_every_commands_help_prints():
    """`dropvision measure --help` raised (a bare % in an option's help): every command's help formats."""
    from identify.app.cli import build_parser as identify_parser

    for parser in (build_parser(), identify_parser()):
        commands = parser._subparsers._group_actions[0].choices
        assert len(commands) >= 6
        for name, sub in commands.items():
            assert sub.prog.split()[-1] in sub.format_help(), name
