"""Outputs never destroy what dropvision did not write (issue: data loss).

Every refusal is exit status 2 with one line naming the path, before anything is written, and
the inputs are byte-identical afterwards (hashes before/after).
"""

import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest

from dvcore.atomic import (
    MARKER,
    OutputError,
    atomic_dir,
    check_output_file,
    claim_dir,
    remove_leftovers,
    write_text,
)
from dropvision.app.campaign import synth_campaign
from dropvision.app.cli import main

SMALL = {"width_px": 128, "height_px": 448, "tip_row": 30.3, "axis_col": 63.6,
         "delays_us": tuple(float(d) for d in range(0, 1501, 60)), "noise": 0.3}


def tree_hashes(root: Path) -> dict:
    """Relative path -> SHA-256 of every file below ``root``."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    root = tmp_path_factory.mktemp("safety") / "grid"
    synth_campaign(root, [70.0], [25.0, 30.0], workers=1, progress=False, overrides=SMALL)
    return root


@pytest.fixture()
def seq(grid, tmp_path):
    """A private copy of one sequence (tests may try to destroy it)."""
    dst = tmp_path / "user" / "seq2"
    shutil.copytree(next(p for p in sorted(grid.iterdir()) if p.is_dir()), dst)
    return dst


def _refused(capsys, argv, *fragments):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for f in fragments:
        assert f in err, err
    return err


def test_measure_out_equal_to_inside_or_around_the_input_is_refused(seq, capsys):
    before = tree_hashes(seq.parent)
    _refused(capsys, ["measure", str(seq), "--out", str(seq)], "would replace the input")
    _refused(capsys, ["measure", str(seq), "--out", str(seq / "result")], "inside the input")
    _refused(capsys, ["measure", str(seq), "--out", str(seq.parent)], "contains the input")
    _refused(capsys, ["measure", str(seq), "--out", str(seq.parent), "--overwrite"], "contains the input")
    _refused(capsys, ["measure", str(seq / "sequence.json"), "--out", str(seq)], "would replace the input")
    assert tree_hashes(seq.parent) == before


def test_measure_into_a_users_folder_is_refused_or_merged_keeping_their_files(seq, tmp_path, capsys):
    out = tmp_path / "results"
    out.mkdir()
    (out / "notes.txt").write_text("my notes")
    _refused(capsys, ["measure", str(seq), "--out", str(out)], "notes.txt", "--overwrite")
    assert sorted(os.listdir(out)) == ["notes.txt"]
    # --overwrite writes ours into it; the user's file stays
    assert main(["measure", str(seq), "--out", str(out), "--overwrite", "--csv"]) == 0
    assert (out / "notes.txt").read_text() == "my notes"
    assert {"frames.parquet", "frames.csv", "summary.json", "notes.txt"} <= set(os.listdir(out))
    # again without --csv: our stale frames.csv goes, the user's notes stay
    assert main(["measure", str(seq), "--out", str(out), "--overwrite"]) == 0
    assert (out / "notes.txt").read_text() == "my notes" and not (out / "frames.csv").exists()
    capsys.readouterr()


def test_measure_replaces_only_its_own_earlier_result(seq, tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["measure", str(seq), "--out", str(out), "--csv"]) == 0
    first = json.loads((out / MARKER).read_text())
    assert set(first["files"]) == {"frames.parquet", "bodies.parquet", "frames.csv", "per_delay.parquet", "summary.json"}
    assert main(["measure", str(seq), "--out", str(out)]) == 0  # ours: replaced as a whole
    assert not (out / "frames.csv").exists()
    (out / "my_plot.png").write_bytes(b"user data")  # the user adds a file to our output
    _refused(capsys, ["measure", str(seq), "--out", str(out)], "my_plot.png")
    assert (out / "my_plot.png").read_bytes() == b"user data"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["measure", str(seq), "--out", str(empty)]) == 0  # an empty folder is fine
    capsys.readouterr()


def test_measure_out_that_is_a_file_below_a_file_or_a_link_is_refused(seq, tmp_path, capsys):
    f = tmp_path / "a.txt"
    f.write_text("keep me")
    _refused(capsys, ["measure", str(seq), "--out", str(f)], "not a folder")
    _refused(capsys, ["measure", str(seq), "--out", str(f), "--overwrite"], "not a folder")
    _refused(capsys, ["measure", str(seq), "--out", str(f / "sub")], "is a file")
    assert f.read_text() == "keep me"
    link = tmp_path / "link"
    link.symlink_to(seq, target_is_directory=True)
    before = tree_hashes(seq)
    _refused(capsys, ["measure", str(seq), "--out", str(link)])
    assert tree_hashes(seq) == before


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_measure_into_a_read_only_folder_is_one_line(seq, tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        _refused(capsys, ["measure", str(seq), "--out", str(ro / "out")], str(ro))
    finally:
        ro.chmod(0o700)


def test_rerun_file_that_is_not_a_recording_is_never_replaced(seq, tmp_path, capsys):
    f = tmp_path / "thesis.rrd"
    f.write_text("not a recording")
    _refused(capsys, ["measure", str(seq), "--out", str(tmp_path / "o"), "--rerun", str(f)], "not a Rerun recording")
    assert f.read_text() == "not a recording" and not (tmp_path / "o").exists()


def test_synth_refuses_a_users_folder_and_replaces_on_request(tmp_path, capsys):
    out = tmp_path / "s"
    out.mkdir()
    (out / "notes.txt").write_text("x")
    argv = ["synth", str(out), "--delays", "0:200:100", "--no-progress"]
    _refused(capsys, argv, "notes.txt")
    assert os.listdir(out) == ["notes.txt"]
    assert main([*argv, "--overwrite"]) == 0
    assert not (out / "notes.txt").exists() and (out / "sequence.json").exists()
    assert main(argv) == 0  # now ours: replaced without asking
    capsys.readouterr()


def test_campaign_out_inside_or_around_a_sequence_is_refused(grid, tmp_path, capsys):
    root = tmp_path / "root"
    shutil.copytree(grid, root)
    before = tree_hashes(root)
    seq = next(p for p in sorted(root.iterdir()) if p.is_dir())
    _refused(capsys, ["campaign", str(root), "--out", str(seq / "ds"), "--workers", "1", "--no-progress"],
             "inside the input")
    _refused(capsys, ["campaign", str(root), "--out", str(root), "--workers", "1", "--no-progress"],
             "contains the input")
    assert tree_hashes(root) == before


def test_campaign_keeps_a_users_tmp_files_and_removes_only_its_own(grid, tmp_path, capsys):
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "notes.tmp").write_text("mine")
    (ds / ".draft.tmp").write_text("mine too")
    _refused(capsys, ["campaign", str(grid), "--out", str(ds), "--workers", "1", "--no-progress"], "--overwrite")
    assert main(["campaign", str(grid), "--out", str(ds), "--workers", "1", "--no-progress", "--overwrite"]) == 0
    ours = ds / ".dvtmp.dataset.json.abc123.tmp"  # what a killed write of ours leaves
    ours.write_text("{")
    assert main(["campaign", str(grid), "--out", str(ds), "--workers", "1", "--no-progress"]) == 0  # resume
    assert (ds / "notes.tmp").read_text() == "mine" and (ds / ".draft.tmp").read_text() == "mine too"
    assert not ours.exists()
    capsys.readouterr()


def test_identify_fit_never_replaces_a_file_that_is_not_a_model(tmp_path, capsys):
    from identify.app.cli import main as identify_main

    f = tmp_path / "model.json"
    f.write_text('{"my": "data"}')
    assert identify_main(["fit", str(tmp_path / "no_dataset"), "--out", str(f)]) == 2
    assert "not written by dropvision" in capsys.readouterr().err
    assert f.read_text() == '{"my": "data"}'


# ----------------------------------------------------------------------------- the primitives
def test_atomic_dir_refuses_before_the_body_runs(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "x.txt").write_text("user")
    ran = []
    with pytest.raises(OutputError, match="x.txt"):
        with atomic_dir(out):
            ran.append(1)
    assert not ran and sorted(os.listdir(tmp_path)) == ["out"]


def test_merge_refuses_a_same_named_folder_holding_user_files(tmp_path):
    out = tmp_path / "out"
    (out / "sub").mkdir(parents=True)
    (out / "sub" / "u.txt").write_text("user")
    with pytest.raises(OutputError, match="sub"):
        with atomic_dir(out, overwrite=True) as tmp:
            (tmp / "sub").mkdir()
            write_text(tmp / "sub" / "a.txt", "ours")
    assert (out / "sub" / "u.txt").read_text() == "user" and not (out / "sub" / "a.txt").exists()
    assert sorted(os.listdir(tmp_path)) == ["out"]


def test_a_forged_marker_cannot_delete_outside_the_folder(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    out = tmp_path / "out"
    out.mkdir()
    (out / "u.txt").write_text("user")
    (out / MARKER).write_text(json.dumps({"schema": "dropvision.output-marker/1", "files": ["../victim.txt"]}))
    with atomic_dir(out, overwrite=True) as tmp:
        write_text(tmp / "a.txt", "ours")
    assert victim.read_text() == "keep" and (out / "u.txt").read_text() == "user"


def test_claim_dir_and_output_files(tmp_path):
    d = claim_dir(tmp_path / "new")
    assert (d / MARKER).exists()
    claim_dir(d)  # ours: accepted again
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "a").write_text("a")
    with pytest.raises(OutputError):
        claim_dir(tmp_path / "user")
    assert claim_dir(tmp_path / "user", is_ours=lambda p: True)
    f = tmp_path / "f.json"
    f.write_text("{}")
    with pytest.raises(OutputError, match="not written by dropvision"):
        check_output_file(f)
    check_output_file(f, is_ours=lambda p: True)
    check_output_file(f, overwrite=True)
    with pytest.raises(OutputError, match="replace the input"):
        check_output_file(f, inputs=[f], overwrite=True)
    with pytest.raises(OutputError, match="is a folder"):
        check_output_file(tmp_path / "user", overwrite=True)


def test_remove_leftovers_touches_only_our_names(tmp_path):
    names = [".dvtmp.x.json.ab12cd.tmp", ".dvtmp.shard.k3j2.old", ".notes.tmp", "a.tmp", ".dvtmp-other"]
    for n in names:
        (tmp_path / n).write_text("x")
    remove_leftovers(tmp_path)
    assert sorted(os.listdir(tmp_path)) == sorted([".notes.tmp", "a.tmp", ".dvtmp-other"])
