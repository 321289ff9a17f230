"""Closed-loop tuning (identify.tuning, `identify tune`) and its rigs (dropvision.app.rigs)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from dropvision.app.campaign import run_campaign, synth_campaign
from dropvision.app.demo import CAMPAIGN_OVERRIDES, campaign_grid
from dropvision.app.rigs import FolderRig, SimulatedPrinthead
from dropvision.synth.writer import write_synthetic_sequence
from identify.dataset_checks import load_dataset
from identify.hybrid import HybridModel
from identify.hybrid_fit import fit_hybrid
from dvcore.schema import TUNING, SchemaError
from identify.tuning import CallableRig, load_rig, read_tuning, tune, update_bias, write_tuning

#: seconds per test (fitted models, campaigns, subprocesses): left out of `make test-fast`
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_model_path(tmp_path_factory):
    """The model `demo --quick` fits: its 3 x 3 synthetic campaign (nominal ink), rendered and measured."""
    root = tmp_path_factory.mktemp("tune")
    u1, u2 = campaign_grid(quick=True)
    synth_campaign(root / "campaign", u1, u2, workers=1, progress=False, overrides=CAMPAIGN_OVERRIDES)
    run_campaign(root / "campaign", root / "dataset", workers=1, progress=False)
    ds = load_dataset(root / "dataset")
    path = root / "model.json"
    fit_hybrid(ds, folds=len(ds.summary), arx=False).model.save(path)
    return path


@pytest.fixture(scope="module")
def demo_model(demo_model_path):
    return HybridModel.from_json(demo_model_path)


def test_update_bias_is_the_conjugate_normal_update():
    # constant bias: precision-weighted mean shrunk by the prior
    b = update_bias([0.10, 0.12], [0.01, 0.01], 0.05)
    precision = 1 / 0.05**2 + 2 / 0.01**2
    assert b.mean == pytest.approx((0.22 / 0.01**2) / precision)
    assert b.se == pytest.approx(precision ** -0.5) and b.n_shots == 2
    # a Gaussian process with a very long correlation length is the same constant
    g = update_bias([0.10, 0.12], [0.01, 0.01], 0.05, positions=[(0, 0), (0.1, 0)], lengthscale=1e4)
    assert g.mean == pytest.approx(b.mean, rel=1e-6) and g.se == pytest.approx(b.se, rel=1e-4)
    # far from every shot the prior comes back; at the last shot that shot dominates
    far = update_bias([0.10, 0.12], [0.01, 0.01], 0.05, positions=[(0, 0), (0.1, 0)], at=(5, 5), lengthscale=0.25)
    assert abs(far.mean) < 1e-6 and far.se == pytest.approx(0.05)
    near = update_bias([0.10, 0.02], [0.01, 0.01], 0.05, positions=[(0, 0), (2, 0)], lengthscale=0.25)
    assert near.mean == pytest.approx(0.02 / (1 + 0.01**2 / 0.05**2), rel=1e-3)
    # nothing measured: the prior
    assert update_bias([float("nan")], [0.01], 0.05).mean == 0.0


def _plant(model, gain=1.08, slope=0.002):
    """A printhead whose volume is the model's x gain (+ a slope in u1), velocity x 1.03."""
    def fire(u1, u2):
        p = model.predict(u1, u2)
        return {"inflight_volume_nl": p["inflight_volume_nl"] * (gain + slope * (u1 - 65)),
                "jetting_velocity_m_s": p["jetting_velocity_m_s"] * 1.03, "operator": 7.0}
    return fire


def test_callable_rig_tunes_a_biased_plant(demo_model, tmp_path, demo_model_path):
    target = 20.0
    res = tune(demo_model, CallableRig(_plant(demo_model), name="lab"), target, seed=3, model_path=demo_model_path)
    df = res.to_pandas()
    assert res.converged and len(df) <= 3
    assert abs(df.volume_error_percent.iloc[0]) > 5  # open loop: the plant's 8 % bias
    assert abs(res.final_volume_error_percent) <= 0.5
    assert df.volume_bias_percent.iloc[-1] == pytest.approx(8.0, abs=1.0)
    assert list(df.columns[: len(TUNING.column_names)]) == TUNING.column_names and "rig_operator" in df
    assert (df.volume_one_drop_low_nl < df.corrected_volume_nl).all()
    assert (df.corrected_volume_nl < df.volume_one_drop_high_nl).all()
    # reproducible, written and read back
    again = tune(demo_model, CallableRig(_plant(demo_model), name="lab"), target, seed=3)
    pd.testing.assert_frame_equal(df, again.to_pandas())
    write_tuning(res, tmp_path / "run")
    back = read_tuning(tmp_path / "run")
    pd.testing.assert_frame_equal(back.to_pandas(), df, check_dtype=False)
    assert back.meta["model_sha256"] == res.meta["model_sha256"] and len(back.meta["model_sha256"]) == 64
    assert back.meta["seed"] == 3 and back.meta["rig"] == "lab" and back.converged
    assert back.meta["versions"]["numpy"] == np.__version__


def test_velocity_target_and_budget(demo_model):
    p = demo_model.predict(65.0, 27.5)
    res = tune(demo_model, _plant(demo_model), p["inflight_volume_nl"], p["jetting_velocity_m_s"], shots=4)
    df = res.to_pandas()
    assert abs(df.velocity_error_percent.iloc[0]) > 2  # the plant is 3 % faster
    assert res.converged and abs(df.velocity_error_percent.iloc[-1]) <= 1.0
    # a budget of one shot that cannot meet the target: not converged, the message says so
    one = tune(demo_model, _plant(demo_model), 20.0, shots=1)
    assert not one.converged and len(one.shots) == 1 and "not met" in one.message
    # a target outside the printable region: the nearest point twice, then it stops
    far = tune(demo_model, _plant(demo_model), 60.0, shots=5)
    assert not far.converged and len(far.shots) == 2 and not far.shots[-1]["feasible"]
    assert "outside the printable region" in far.message and "stopped after 2 of 5 shots" in far.message


def test_an_interrupted_run_keeps_its_shots(demo_model, tmp_path):
    plant = _plant(demo_model)

    def fire(u1, u2, shot):
        if shot == 2:
            raise OSError("camera lost")
        return plant(u1, u2)

    with pytest.raises(OSError, match="camera lost"):
        tune(demo_model, fire, 20.0, progress=lambda so_far: write_tuning(so_far, tmp_path / "run"))
    back = read_tuning(tmp_path / "run")
    assert len(back.shots) == 1 and back.message.startswith("in progress: 1 of at most 5") and not back.converged


def test_rig_answers_are_checked(demo_model):
    with pytest.raises(ValueError, match=r"^rig lab: shot 1: no in-flight volume measured"):
        tune(demo_model, CallableRig(lambda u1, u2, shot: (float("nan"), 1.0), name="lab"), 20.0)
    with pytest.raises(ValueError, match="rig returned str"):
        tune(demo_model, CallableRig(lambda u1, u2: "20 nl", name="lab"), 20.0)
    with pytest.raises(ValueError, match="^shots must be an integer >= 1"):
        tune(demo_model, _plant(demo_model), 20.0, shots=0)
    with pytest.raises(ValueError, match="unknown rig"):
        load_rig("nosuch")
    assert isinstance(load_rig("simulated", viscosity_factor=1.2), SimulatedPrinthead)


def test_simulated_printhead_viscosity(demo_model, demo_model_path, tmp_path):
    """The demo model (nominal ink) tunes a printhead with 1.2 x the viscosity: error shrinks."""
    rig = SimulatedPrinthead(viscosity_factor=1.2, width_px=96, height_px=320, seed=0)
    res = tune(demo_model, rig, 20.0, shots=3, seed=0, samples=500, model_path=demo_model_path)
    df = res.to_pandas()
    assert abs(df.volume_error_percent.iloc[0]) > 4  # open loop on this plant
    assert abs(res.final_volume_error_percent) < abs(res.open_loop_volume_error_percent) / 5
    assert abs(res.final_volume_error_percent) <= 0.5 and res.converged
    # the measurement agrees with the plant's truth, and the table is complete
    assert np.allclose(df.measured_volume_nl, df.rig_truth_inflight_volume_nl, rtol=0.005)
    no_target = ["design_target_velocity_m_s", "velocity_error_percent"]  # no velocity target: NaN
    assert not df[TUNING.column_names].drop(columns=no_target).isna().any().any()
    assert res.meta["rig_options"]["viscosity_factor"] == 1.2


def test_folder_rig_measures_what_appears(tmp_path):
    sim = SimulatedPrinthead(nozzle_diameter_factor=0.97, width_px=96, height_px=320)
    write_synthetic_sequence(sim.config(65.0, 27.5, 1), tmp_path / "shots" / "shot_01")
    messages = []

    class Out:
        def write(self, text):
            messages.append(text)

        def flush(self):
            pass

    rig = FolderRig(tmp_path / "shots", timeout_s=5, poll_s=0.05, out=Out())
    shot = rig(65.0, 27.5, 1)
    assert shot.inflight_volume_nl == pytest.approx(sim.truth(65.0, 27.5)["inflight_volume_nl"], rel=0.005)
    assert "u1 = 65.000 um/ms, u2 = 27.500 um" in "".join(messages) and "shot_01" in "".join(messages)
    with pytest.raises(ValueError, match=r"shot_02: no sequence.json after 0.2 s"):
        FolderRig(tmp_path / "shots", timeout_s=0.2, poll_s=0.05, out=Out())(65.0, 27.5, 2)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "identify.app.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=300)


def test_cli_tune_simulated_and_errors(demo_model_path, tmp_path):
    out = tmp_path / "tune"
    r = _cli("tune", demo_model_path, "--volume-nl", 20, "--rig", "simulated", "--viscosity-factor", 1.2,
             "--shots", 3, "--seed", 0, "--samples", 300, "--out", out)
    assert r.returncode == 0, r.stderr
    assert "shot 1:" in r.stdout and "met in" in r.stdout
    back = read_tuning(out)
    assert back.meta["rig_options"]["viscosity_factor"] == 1.2 and back.converged
    assert math.isfinite(back.shots[-1]["measured_volume_nl"])
    # --json: one document, NaN as null; a budget spent off target exits 1
    r = _cli("tune", demo_model_path, "--volume-nl", 20, "--rig", "simulated", "--viscosity-factor", 1.2,
             "--shots", 1, "--samples", 300, "--json", "--out", tmp_path / "one")
    doc = json.loads(r.stdout)
    assert r.returncode == 1 and doc["converged"] is False and doc["shots"][0]["design_target_velocity_m_s"] is None
    assert doc["shots"][0]["volume_error_percent"] > 4
    # errors: one line, exit 2
    for args, msg in (
        (("--rig", "nosuch"), "unknown rig"),
        (("--rig", "identify.nosuch:fire"), "cannot load the function"),
        (("--rig", "folder"), "--rig folder needs --rig-folder"),
    ):
        r = _cli("tune", demo_model_path, "--volume-nl", 20, *args, "--out", tmp_path / "x")
        assert r.returncode == 2 and msg in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = _cli("tune", tmp_path / "missing.json", "--volume-nl", 20, "--rig", "simulated", "--out", tmp_path / "y")
    assert r.returncode == 2 and "missing.json" in r.stderr
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    r = _cli("tune", demo_model_path, "--volume-nl", 20, "--rig", "simulated", "--out", tmp_path / "mine")
    assert r.returncode == 2 and "shot 1" not in r.stdout and (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def test_read_tuning_names_the_bad_file(demo_model, tmp_path):
    res = tune(demo_model, _plant(demo_model), 20.0, shots=1)
    write_tuning(res, tmp_path / "run")
    df = pd.read_parquet(tmp_path / "run" / "tuning.parquet").drop(columns="measured_volume_nl")
    df.to_parquet(tmp_path / "run" / "tuning.parquet")
    with pytest.raises(SchemaError, match=r"tuning.parquet: missing column 'measured_volume_nl'"):
        read_tuning(tmp_path / "run")


def test_read_tuning_refuses_hostile_json_naming_the_file(demo_model, tmp_path):
    """tuning.json is read with the hardened reader (dvcore.jsonio): NaN/Infinity are refused."""
    res = tune(demo_model, _plant(demo_model), 20.0, shots=1)
    write_tuning(res, tmp_path / "run")
    doc = tmp_path / "run" / "tuning.json"
    doc.write_text(doc.read_text().replace('"target_volume_nl": 20.0', '"target_volume_nl": Infinity', 1))
    with pytest.raises(SchemaError, match=r"tuning\.json: invalid JSON \(Infinity is not a JSON number"):
        read_tuning(tmp_path / "run")
    doc.unlink()
    with pytest.raises(FileNotFoundError, match=r"tuning\.json: missing file"):
        read_tuning(tmp_path / "run")


def test_rerun_view_of_a_run(demo_model, tmp_path):
    from identify.app import rerun_log as irl
    from dvcore.rerun_options import RerunOptions
    from rrdtools import Rrd

    res = tune(demo_model, _plant(demo_model), 20.0)
    rec = irl.open_identify_recording(RerunOptions(path=tmp_path / "tune.rrd", application_id="dv_test"))
    try:
        irl.log_tuning(rec, res, model=demo_model)
    finally:
        irl.close_recording(rec)
    rrd = Rrd(tmp_path / "tune.rrd")
    assert {"/identify/tuning/volume_nl/measured", "/identify/tuning/volume_nl/target",
            "/identify/tuning/volume_nl/one_drop_low", "/identify/tuning/controls/path",
            "/identify/tuning/table"} <= rrd.entities()
    batch = rrd.temporal["/identify/tuning/volume_nl/measured"][0]
    assert batch.column("shot").to_pylist() == [s["shot"] for s in res.shots]
    assert [v[0] for v in batch.column("Scalars:scalars").to_pylist()] == pytest.approx(
        [s["measured_volume_nl"] for s in res.shots])
    assert res.message in rrd.static["/identify/tuning/table"]["TextDocument:text"][0]


def test_tuning_columns_are_declared_and_library_errors_name_parameters():
    """Every per-output column `tune` writes is a declared tuning.parquet column; a bad value is said
    with the parameter's name by the library and with the option's by the command line's boundary."""
    from dvcore.errors import ParameterError, describe
    from dvcore.schema import TUNING
    from identify.tuning import OUTPUT_COLUMNS

    names = [c for cols in OUTPUT_COLUMNS.values() for c in vars(cols).values()]
    assert len(names) == 20 and set(names) <= set(TUNING.column_names)
    with pytest.raises(ParameterError, match="^volume_nl must be a positive number") as caught:
        tune(None, None, -1.0)
    assert describe(caught.value) == "--volume-nl must be a positive number, got -1.0"
    with pytest.raises(ParameterError) as caught:
        load_rig("nosuch")
    assert describe(caught.value).startswith("--rig nosuch: unknown rig")
