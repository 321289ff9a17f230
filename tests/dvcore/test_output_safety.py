"""Outputs never destroy what dropvision did not write (issue: data loss).

Every refusal is exit status 2 with one line naming the path, before anything is written, and
the inputs are byte-identical afterwards (hashes before/after).
"""

import errno
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


def test_synth_overwrite_never_empties_a_folder_it_did_not_write(tmp_path, capsys, monkeypatch):
    out = tmp_path / "s"
    out.mkdir()
    (out / "notes.txt").write_text("x")
    argv = ["synth", str(out), "--delays", "0:200:100", "--no-progress", "--size", "64x96"]
    _refused(capsys, argv, "notes.txt")
    _refused(capsys, [*argv, "--overwrite"], "not written by dropvision", str(out))
    monkeypatch.chdir(out)  # the user stands in it: still refused, never emptied nor removed
    _refused(capsys, ["synth", ".", "--delays", "0:200:100", "--no-progress", "--overwrite"], "notes.txt")
    _refused(capsys, ["synth", "..", "--delays", "0:200:100", "--no-progress", "--overwrite"], "not written")
    assert os.listdir(out) == ["notes.txt"] and os.getcwd() == str(out)
    # a folder of ours: replaced without asking; --overwrite keeps a file the user added to it
    ours = tmp_path / "ours"
    argv = ["synth", str(ours), "--delays", "0:200:100", "--no-progress", "--size", "64x96"]
    assert main(argv) == 0
    (ours / "notes.txt").write_text("mine")
    _refused(capsys, argv, "notes.txt", "--overwrite")
    assert main([*argv[:3], "0:100:100", *argv[4:], "--overwrite"]) == 0  # 2 frames instead of 3
    assert (ours / "notes.txt").read_text() == "mine"
    assert len(json.loads((ours / "sequence.json").read_text())["frames"]) == 2
    assert len([f for f in os.listdir(ours) if f.endswith(".png")]) == 2  # our earlier third frame removed
    # rendered again while the user stands inside it: written in place, the folder never moved
    (ours / "notes.txt").unlink()
    monkeypatch.chdir(ours)
    inode = os.stat(ours).st_ino
    assert main(["synth", ".", "--delays", "0:300:100", "--no-progress", "--size", "64x96"]) == 0
    assert os.stat(ours).st_ino == inode and os.path.samefile(os.getcwd(), ours)
    assert len(json.loads((ours / "sequence.json").read_text())["frames"]) == 4
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".dvtmp")]
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


# ----------------------------------------------------------------------------- one run per output (issue 29)
def _holder(folder: Path):
    """Another process holding the output lock of ``folder`` until its stdin closes."""
    import subprocess
    import sys

    code = ("import sys; from dvcore.atomic import output_lock\n"
            "with output_lock(sys.argv[1]):\n    print('held', flush=True); sys.stdin.read()\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(folder)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])})
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_an_output_written_by_a_live_run_is_refused_at_once(grid, seq, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["measure", str(seq), "--out", str(out)]) == 0  # an earlier result of ours
    before = tree_hashes(out)
    proc = _holder(out)
    try:
        for argv in (["measure", str(seq), "--out", str(out)],
                     ["watch", str(seq), "--out", str(out), "--idle-s", "0.1"],
                     ["campaign", str(grid), "--out", str(out), "--workers", "1", "--no-progress"]):
            _refused(capsys, argv, str(out), f"another dropvision run (process {proc.pid}) is writing this output")
        assert tree_hashes(out) == before
    finally:
        proc.kill()  # killed: the operating system releases its lock
        proc.wait()
        proc.stdin.close()
        proc.stdout.close()
    assert main(["measure", str(seq), "--out", str(out)]) == 0
    assert sorted(n for n in os.listdir(tmp_path) if n.startswith(".dvtmp")) == []  # lock file removed after


def test_cleanup_removes_only_temporaries_of_dead_runs(tmp_path):
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    live = ".dvtmp.manifest.json.%d.abcd_123.tmp" % os.getppid()
    stale = ".dvtmp.manifest.json.%d.abcd_123.tmp" % dead.pid
    for name in (live, stale, ".dvtmp.x.json.ab12cd.tmp"):
        (tmp_path / name).write_text("{")
    remove_leftovers(tmp_path)
    assert sorted(os.listdir(tmp_path)) == [live]
    write_text(tmp_path / "a.json", "{}")  # our temporary names carry our process id
    mine = []
    real = os.replace
    try:
        os.replace = lambda src, dst: (mine.append(Path(src).name), real(src, dst))[1]
        write_text(tmp_path / "b.json", "{}")
    finally:
        os.replace = real
    assert mine and f".{os.getpid()}." in mine[0] and mine[0].startswith(".dvtmp.b.json.")


# ----------------------------------------------------------------------------- mount points, devices
def _ours_with(folder: Path, text: str) -> None:
    with atomic_dir(folder) as tmp:
        write_text(tmp / "a.txt", text)
        write_text(tmp / "old.txt", "x")


def test_a_mount_point_is_written_in_place_never_renamed(tmp_path, monkeypatch):
    out = tmp_path / "mnt"
    _ours_with(out, "1")
    inode = os.stat(out).st_ino
    real = os.path.ismount
    monkeypatch.setattr(os.path, "ismount", lambda p: Path(p) == out or real(p))

    def no_rename_of_the_mount(src, dst, *, _real=os.replace):
        if Path(src) == out or Path(dst) == out:
            raise OSError(errno.EBUSY, "Device or resource busy", str(src))
        return _real(src, dst)

    monkeypatch.setattr(os, "replace", no_rename_of_the_mount)
    with atomic_dir(out) as tmp:
        assert tmp.parent == out  # staged on the mounted volume itself
        write_text(tmp / "a.txt", "2")
    assert os.stat(out).st_ino == inode and (out / "a.txt").read_text() == "2"
    assert sorted(os.listdir(out)) == [MARKER, "a.txt"]  # our earlier old.txt removed
    assert os.listdir(tmp_path) == ["mnt"]


@pytest.mark.parametrize("code", [errno.EBUSY, errno.EXDEV])
def test_a_folder_that_cannot_be_renamed_is_replaced_file_by_file(tmp_path, monkeypatch, code):
    out = tmp_path / "out"
    _ours_with(out, "1")
    real = os.replace

    def refuse_the_folder(src, dst):
        if Path(src) == out:  # a bind mount: the kernel refuses to move it
            raise OSError(code, os.strerror(code), str(src), None, str(dst))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", refuse_the_folder)
    with atomic_dir(out) as tmp:
        write_text(tmp / "a.txt", "2")
    assert (out / "a.txt").read_text() == "2" and sorted(os.listdir(out)) == [MARKER, "a.txt"]
    assert os.listdir(tmp_path) == ["out"]  # no empty .dvtmp.*.old left beside it


def test_a_cross_device_failure_names_the_folder_and_leaves_nothing(seq, tmp_path, monkeypatch, capsys):
    out = tmp_path / "o"
    assert main(["measure", str(seq), "--out", str(out)]) == 0
    before = tree_hashes(out)
    real = os.replace

    def cross_device(src, dst):
        if Path(dst) == out or Path(dst).parent == out or Path(src) == out:
            raise OSError(errno.EXDEV, "Invalid cross-device link", str(src), None, str(dst))
        return real(src, dst)

    monkeypatch.setattr(os, "replace", cross_device)
    _refused(capsys, ["measure", str(seq), "--out", str(out)], str(out), "cannot move the result into place",
             "Invalid cross-device link")
    assert tree_hashes(out) == before
    assert sorted(os.listdir(tmp_path)) == sorted(["o", "user"])


# ----------------------------------------------------------------------------- modes, a full disk
@pytest.mark.parametrize("mask, file_mode, dir_mode", [(0o022, 0o644, 0o755), (0o027, 0o640, 0o750)])
def test_outputs_follow_the_umask(tmp_path, mask, file_mode, dir_mode):
    from dropvision.app.live_journal import Journal

    old = os.umask(mask)
    try:
        with atomic_dir(tmp_path / "out") as tmp:
            write_text(tmp / "a.json", "{}")
            (tmp / "sub").mkdir()
        claimed = claim_dir(tmp_path / "ds")
        write_text(claimed / "m.json", "{}")
        Journal(claimed / "j.jsonl").close()
    finally:
        os.umask(old)
    out = tmp_path / "out"
    assert oct(out.stat().st_mode & 0o777) == oct(dir_mode)
    assert oct((out / "sub").stat().st_mode & 0o777) == oct(dir_mode)
    for f in (out / "a.json", out / MARKER, claimed / "m.json", claimed / MARKER, claimed / "j.jsonl"):
        assert oct(f.stat().st_mode & 0o777) == oct(file_mode), f
    assert oct(claimed.stat().st_mode & 0o777) == oct(dir_mode)


def test_a_full_disk_names_the_output_being_written(seq, tmp_path, monkeypatch, capsys):
    import pandas as pd

    def full(self, *args, **kwargs):  # what pyarrow raises: an errno, no file name
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_parquet", full)
    out = tmp_path / "o"
    err = _refused(capsys, ["measure", str(seq), "--out", str(out)], f"{out}: No space left on device")
    assert str(seq) not in err.replace(str(out), "")
    assert not out.exists() and not [n for n in os.listdir(tmp_path) if n.startswith(".dvtmp")]

    def no_fsync(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", no_fsync)
    with pytest.raises(OSError, match="No space left") as caught:
        write_text(tmp_path / "x.json", "{}")
    assert caught.value.filename == str(tmp_path / "x.json") and os.listdir(tmp_path) == sorted(os.listdir(tmp_path))
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".dvtmp")]


# ----------------------------------------------------------------------------- recordings
def test_a_recording_inside_the_output_or_the_input_is_refused_before_measuring(seq, tmp_path, capsys):
    out = tmp_path / "o4"
    before = tree_hashes(seq)
    _refused(capsys, ["measure", str(seq), "--out", str(out), "--rerun", str(out / "rec.rrd")],
             str(out / "rec.rrd"), "inside the output folder")
    assert not out.exists()
    _refused(capsys, ["measure", str(seq), "--out", str(out), "--rerun", str(seq / "rec.rrd")],
             str(seq / "rec.rrd"), "inside the input folder")
    _refused(capsys, ["watch", str(seq), "--out", str(out), "--rerun", str(seq / "rec.rrd"), "--idle-s", "0.1"],
             "inside the input folder")
    assert tree_hashes(seq) == before and not out.exists()


def test_an_output_file_inside_an_input_folder_is_refused(tmp_path):
    """A file output (a model, a table) may not replace an input nor go inside an input folder,
    whatever --overwrite says: it would change (or destroy) the data read."""
    from dvcore.atomic import OutputError, check_output_file

    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "summary.parquet").write_bytes(b"data")
    for target, inputs, message in ((ds / "summary.parquet", [ds / "summary.parquet"], "would replace the input"),
                                    (ds / "summary.parquet", [ds], "lies inside the input"),
                                    (ds / "model.json", [ds], "lies inside the input")):
        with pytest.raises(OutputError, match=message):
            check_output_file(target, inputs=inputs, overwrite=True)
    assert check_output_file(tmp_path / "model.json", inputs=[ds]) == tmp_path / "model.json"
    assert (ds / "summary.parquet").read_bytes() == b"data"
