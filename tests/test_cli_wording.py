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
