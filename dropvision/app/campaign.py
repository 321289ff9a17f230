"""Campaigns: many strobe sequences -> the training dataset that `identify` reads.

`dropvision campaign ROOT --out DATASET` finds every sequence (a folder holding a
``sequence.json``) and every shot folder below ROOT, measures each one in a worker (one task per sequence; the
worker receives paths, writes the sequence's shard and returns only a small summary) and
writes the dataset:

- ``timeseries.parquet``: sequence_id, u1_um_per_ms, u2_um, delay_us, grown_volume_nl,
  flow_velocity_m_s, attached — one row per strobe delay (repeated frames at one delay are
  averaged over their attached frames; ``attached`` is True when every frame at that delay
  still shows the drop joined to the nozzle); in a campaign of another waveform template
  (sequence.json ``waveform`` in the template form, e.g. three_pulse) the template's parameters
  take the place of u1_um_per_ms, u2_um here and in summary.parquet, and dataset.json records the
  template (``waveform``, ``waveform_parameters``);
- ``summary.parquet``: one row per measured sequence: sequence_id, u1_um_per_ms, u2_um,
  pinchoff_us, grown_volume_at_pinchoff_nl, inflight_volume_nl, jetting_velocity_m_s,
  flow_velocity_at_max_stroke_m_s (+ inflight_volume_std_nl, jetting_velocity_se_m_s,
  satellites, n_frames, n_errors);
- ``dataset.json``: nozzle_inner_diameter_um, ink, nozzle (geometry for Eq. 2: length_mm,
  reservoir_channel_radius_um, reservoir_channel_length_mm, from sequence.json's optional
  ``nozzle`` block), sample_interval_us, dead_time_us,
  u3_um_per_ms, hold_us, pixel_size_um, the sequences, software versions;
- ``shots.parquet`` (where ROOT holds shot folders): every row of every shot folder, a folder
  of images with no delay to tell (`dropvision.analysis.shots`: one image per shot, as a drop watcher
  exports them), each folder measured as ``dropvision measure`` measures it
  (`dropvision.analysis.shots.measure_shots`), its id in ``shot_folder``, then its labels as numbers;
- ``shards/<id>/``: each sequence's frames.parquet and summary.json (with its input hash); a
  shot folder's shots.parquet, frames.parquet, bodies.parquet and summary.json;
- ``manifest.json``: each sequence's (and shot folder's, ``kind`` "shots") path, input hash,
  status and error.

The dataset files are built from the shards by `dropvision.app.campaign_dataset`.

Every file is written atomically and the manifest is rewritten as soon as sequences finish
(once per sequence in the serial mode; in the parallel modes once for all that finished since
the last rewrite), so a run killed at any moment loses no finished sequence and never leaves a
half-written shard. Re-running resumes: a sequence whose shard carries the same input hash
(content of its files, the measurement configuration and the dropvision version) is skipped.
"""

from __future__ import annotations

import copy
import dataclasses
import contextlib
import hashlib
import json
import math
import os
import re
import warnings
from concurrent.futures import FIRST_COMPLETED, as_completed, wait
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from dvcore import __version__
from dropvision.app.campaign_dataset import ShardPart, assemble_dataset, sequence_controls, shard_part
from dropvision.app.executors import SerialExecutor, check_executor_args, make_executor
from dropvision.app.options import grouped_warnings, warning_lines
from dropvision.app.rerun_log import RerunLogger
from dropvision.config import MeasureConfig
from dropvision.measurement import measure_sequence
from dropvision.io.readers import IMAGE_SUFFIXES
from dropvision.output.result_writer import check_shots_result, write_result, write_shots_result
from dropvision.io.sequence import check_overrides, open_sequence
from dropvision.io.sequence_meta import SequenceError
from dropvision.analysis.shots import find_shots, is_shot_folder, measure_shots
from dropvision.synth.sequence import SynthConfig
from dropvision.synth.writer import write_synthetic_sequence
from dvcore import schema
from dvcore.atomic import (
    atomic_dir, check_outside_inputs, claim_dir, output_lock, remove_leftovers, to_json, write_bytes,
)
from dvcore.jsonio import load_json_hardened
from dvcore.versions import software_versions

MANIFEST_SCHEMA = schema.MANIFEST.schema
_IGNORED_PREFIXES = (".", "truth")


@dataclass(frozen=True)
class CampaignResult:
    """What a campaign run did."""

    dataset_dir: Path
    measured: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    #: sequence id -> the warnings its measurement gave (one line each, once per sequence)
    warnings: dict[str, list[str]] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "dataset_dir": str(self.dataset_dir),
            "measured": self.measured,
            "skipped": self.skipped,
            "failed": self.failed,
            "warnings": self.warnings,
        }


#: Seconds without CPU used by any local worker process while sequences are awaited, after which
#: the campaign stops with :class:`CampaignStalled` (`dvcore.process.wait_working`; the environment
#: variable ``DROPVISION_WORKER_STALL_S`` sets another value).
CAMPAIGN_STALL_S = 60.0


class CampaignStalled(RuntimeError):
    """The local worker processes used no CPU for :data:`CAMPAIGN_STALL_S` while sequences were
    awaited (a worker blocked for ever): they are killed and the campaign stops, naming the
    sequences in flight; the manifest keeps them pending, so a rerun measures them again."""


def _wait_bounded(executor, pending: dict) -> set:
    """The futures of ``pending`` (future -> sequence id) done next. On a local process pool the
    wait has a bound (:data:`CAMPAIGN_STALL_S` without CPU in its workers: :class:`CampaignStalled`);
    the serial executor's futures are done already; a Dask cluster's workers live elsewhere and
    are watched by its own scheduler."""
    from concurrent.futures import ProcessPoolExecutor

    from dvcore.process import WorkersStalled, end_pool, pool_pids, stall_s, wait_working

    if not isinstance(executor, ProcessPoolExecutor):
        return wait(pending, return_when=FIRST_COMPLETED)[0]
    try:
        return wait_working(pending, lambda: pool_pids(executor), stall_s(CAMPAIGN_STALL_S))[0]
    except WorkersStalled as exc:
        end_pool(executor, kill=True)
        raise CampaignStalled(f"the worker processes stalled ({exc}) while measuring "
                              f"{', '.join(sorted(map(str, pending.values())))}; they were stopped, and a "
                              "rerun of the campaign measures these sequences again") from exc


class CampaignFailed(RuntimeError):
    """Every sequence of a campaign failed: no dataset is written (``manifest.json`` records each
    sequence's error; a partly failed campaign writes its dataset and lists the failures).

    Attributes
    ----------
    result : CampaignResult
        What the run did (``failed``: sequence id -> error).
    """

    def __init__(self, result: CampaignResult, root):
        self.result = result
        sid, error = next(iter(sorted(result.failed.items())), ("?", "unknown error"))
        n = len(result.failed)
        super().__init__(
            f"{root}: {'the only sequence' if n == 1 else f'all {n} sequences'} failed, no dataset written "
            f"(first: {sid}: {' '.join(str(error).split())}); each error is in "
            f"{Path(result.dataset_dir) / 'manifest.json'}")


# ----------------------------------------------------------------------------- discovery
#: Trees of the operating system that hold no data and never end (``/proc/<pid>/root`` leads back
#: to ``/``): never walked, whatever link leads there.
SPECIAL_TREES = ("/proc", "/sys", "/dev")


def _within(path: str, tree: str) -> bool:
    return path == tree or path.startswith(tree.rstrip(os.sep) + os.sep)


def find_sequences(root) -> list[Path]:
    """Every folder below ``root`` (including itself) that holds a sequence.json, sorted.

    Linked folders are followed (campaigns are often assembled from links to the rigs' folders),
    each real folder once; hidden folders are skipped. A link to a folder that holds the link
    itself (``/``, a parent folder: a loop) is not followed, nor one into the system's special
    trees (:data:`SPECIAL_TREES`), so a stray link to ``/`` cannot walk the whole file system.
    The paths returned are below ``root`` as written (the links are not resolved), so sequence
    ids name the campaign's own layout.
    """
    return sorted(Path(dirpath) for dirpath, filenames in _walk(root) if "sequence.json" in filenames)


def find_inputs(root, overrides: dict | None = None) -> list[tuple[Path, str]]:
    """Every sequence and every shot folder below ``root`` (including itself), sorted:
    (folder, ``"sequence"`` or ``"shots"``).

    A shot folder is a folder that `dropvision measure` measures as shots
    (`dropvision.analysis.shots.is_shot_folder`: two or more images with no delay to tell, no frames list
    nor frame rate, ``overrides`` included); every other folder holding a sequence.json is a
    sequence. Folders are walked as `find_sequences` walks them.
    """
    found = []
    for dirpath, filenames in _walk(root):
        folder = Path(dirpath)
        n_images = sum(1 for f in filenames if Path(f).suffix.lower() in IMAGE_SUFFIXES and not f.startswith("."))
        if n_images >= 2 and is_shot_folder(folder, overrides=overrides):
            found.append((folder, "shots"))
        elif "sequence.json" in filenames:
            found.append((folder, "sequence"))
    return sorted(found)


def _walk(root):
    """(folder, its file names) of every folder below ``root`` that `find_sequences` visits."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: campaign root is not a folder")
    real_root = os.path.realpath(root)
    special = [t for t in SPECIAL_TREES if _within(real_root, t)]
    if special:
        raise FileNotFoundError(f"{root}: lies in the system folder {special[0]}, not a campaign root")
    seen = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        real = os.path.realpath(dirpath)
        if real in seen:  # two links to one folder
            dirnames[:] = []
            continue
        seen.add(real)
        keep = []
        for d in sorted(dirnames):
            if d.startswith("."):
                continue
            path = os.path.join(dirpath, d)
            if os.path.islink(path):
                target = os.path.realpath(path)
                # a loop (the target holds this folder or the root) or a special tree: not followed
                if (_within(real, target) or _within(real_root, target)
                        or any(_within(target, t) for t in SPECIAL_TREES)):
                    continue
            keep.append(d)
        dirnames[:] = keep
        yield dirpath, filenames


def sequence_id(root, folder) -> str:
    """Sequence id: the folder's path relative to the campaign root, with '/' separators."""
    rel = Path(os.path.abspath(folder)).relative_to(os.path.abspath(root))
    return rel.as_posix() if rel.parts else Path(root).resolve().name


def shard_name(seq_id: str) -> str:
    """A flat, filesystem-safe, collision-free folder name for a sequence id."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", seq_id).strip("._")[:80] or "sequence"
    return f"{safe}-{hashlib.sha256(seq_id.encode()).hexdigest()[:8]}"


def input_hash(folder, config_repr: str = "", recursive: bool = True) -> str:
    """SHA-256 over the sequence's files (sequence.json and images, not truth files), the
    measurement configuration and the dropvision version. ``recursive=False`` (a shot folder):
    the files of the folder itself, not those of its sub-folders (other inputs of the campaign).

    Only what the measurement may read is read: a link resolving outside the sequence folder
    counts by its name and target, never by the content it points at.
    """
    h = hashlib.sha256()
    h.update(f"dropvision {__version__}\n{config_repr}\n".encode())
    folder = Path(folder)
    real_folder = folder.resolve()
    for path in sorted(p for p in (folder.rglob("*") if recursive else folder.glob("*")) if p.is_file()):
        rel = path.relative_to(folder)
        if any(part.startswith(_IGNORED_PREFIXES) for part in rel.parts):
            continue
        h.update(rel.as_posix().encode() + b"\0")
        target = path.resolve()
        if target != real_folder and real_folder not in target.parents:
            h.update(b"link outside -> " + str(target).encode() + b"\0")
            continue
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()


# ----------------------------------------------------------------------------- worker
def measure_to_shard(seq_dir: str, shard_dir: str, digest: str | None, config=None, rerun_options=None,
                     overrides: dict | None = None, labels: dict | None = None,
                     config_repr: str = "", seq_id: str | None = None) -> dict:
    """Measure one sequence and write its shard atomically. Runs in a worker process.

    ``digest``: the sequence's input hash; None to compute it here first
    (``input_hash(seq_dir, config_repr)``), so that the client need not read every file of the
    campaign itself (the hashing then runs on the workers, in parallel, next to the data).
    ``overrides`` / ``labels``: values of sequence.json keys given for every sequence (options,
    see `dropvision.io.sequence.open_sequence`). ``seq_id``: when given, the worker also reads the
    shard it wrote into its share of the dataset (`shard_part`, key ``part``), so that the
    client does not.

    Returns a small, picklable summary: status ("ok"/"failed"), error, the input hash, the
    sequence's metadata needed for the dataset, the warnings of its measurement (one line
    each; the caller prints them), and the dataset part (or None: the client then reads the
    shard itself).
    """
    caught: list = []
    try:
        if digest is None:
            digest = input_hash(seq_dir, config_repr)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            meta = open_sequence(seq_dir, overrides=overrides, labels=labels).meta
            logger = None
            if rerun_options is not None:
                logger = RerunLogger(rerun_options)
            try:
                result = measure_sequence(seq_dir, config=config or MeasureConfig(), logger=logger,
                                          overrides=overrides, labels=labels)
            finally:
                if logger is not None:
                    logger.close()
        if result.summary.get("kind") == "printhead-row":  # issue 32: no single-nozzle tables to join
            raise SequenceError(f"{seq_dir}: a printhead row (several nozzles under one plate, or a scan of them): a "
                                "campaign's dataset holds single-nozzle sequences; measure it with `dropvision "
                                "measure FOLDER --out OUT` (nozzles.parquet)")
        # shards/ is ours as a whole: an older shard of the same sequence is merged over
        with atomic_dir(shard_dir, inputs=[seq_dir], overwrite=True, kind="campaign-shard") as tmp:
            write_result(result, tmp, extra_summary={"input_hash": digest})
        info = {
            "waveform": meta.waveform,
            "ink": meta.ink,
            "nozzle_inner_diameter_um": meta.nozzle_inner_diameter_um,
            "pixel_size_um": meta.pixel_size_um,
            "nozzle": (meta.extra or {}).get("nozzle"),
        }
        part = None
        if seq_id is not None and sequence_controls(meta.waveform)[2] is None:
            shard = Path(shard_dir)
            try:  # the same reading as the client's, of the files just written
                part = shard_part(shard.parent.parent, seq_id, {"meta": info, "shard": shard.name,
                                                                "input_hash": digest})
            except Exception:  # noqa: BLE001 - left to the client's final assembly, which reports it
                part = None
        return {"status": "ok", "error": None, "input_hash": digest, "meta": info,
                "warnings": warning_lines(caught), "part": part}
    except Exception as exc:  # noqa: BLE001 - a failed sequence must not stop the others
        return {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "input_hash": digest, "meta": None,
                "warnings": warning_lines(caught)}



def measure_shots_to_shard(folder: str, shard_dir: str, digest: str | None, config=None, rerun_options=None,
                           overrides: dict | None = None, labels: dict | None = None,
                           config_repr: str = "", seq_id: str | None = None) -> dict:
    """Measure one shot folder (`dropvision.analysis.shots.measure_shots`, as `dropvision measure` measures
    it) and write its shard atomically: shots.parquet, frames.parquet, bodies.parquet and
    summary.json (the shot folder's, with its input hash). Runs in a worker process; the same
    arguments and the same small summary as `measure_to_shard` (``meta``: kind, images, measured).
    ``rerun_options`` is not used: shots are not logged to Rerun. ``digest`` None: computed here
    (``input_hash(folder, config_repr, recursive=False)``)."""
    caught: list = []
    try:
        if digest is None:
            digest = input_hash(folder, config_repr, recursive=False)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            shots = find_shots(folder, overrides=overrides)
            if shots is None:
                raise SequenceError(f"{folder}: no longer a folder of shots (images with no delay to tell)")
            result = measure_shots(shots, None, config or MeasureConfig(), overrides=overrides, option_labels=labels)
        shard = Path(shard_dir)
        summary = check_shots_result(result, shard, extra_summary={"input_hash": digest})
        # shards/ is ours as a whole: an older shard of the same folder is merged over
        with atomic_dir(shard, inputs=[folder], overwrite=True, kind="campaign-shard") as tmp:
            write_shots_result(result, tmp, summary)
        info = {"kind": "shots", "n_shots": summary["n_shots"], "n_measured": summary["n_measured"]}
        part = None
        if seq_id is not None:
            try:  # the same reading as the client's, of the files just written
                part = shard_part(shard.parent.parent, seq_id, {"kind": "shots", "meta": info, "shard": shard.name,
                                                                "input_hash": digest})
            except Exception:  # noqa: BLE001 - left to the client's final assembly, which reports it
                part = None
        return {"status": "ok", "error": None, "input_hash": digest, "meta": info,
                "warnings": grouped_warnings(warning_lines(caught), {p.name for p in shots.paths}), "part": part}
    except Exception as exc:  # noqa: BLE001 - a failed shot folder must not stop the others
        return {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "input_hash": digest, "meta": None,
                "warnings": warning_lines(caught)}


# ----------------------------------------------------------------------------- dataset
def _load_manifest(path: Path) -> dict:
    if not path.exists():
        return {"schema": MANIFEST_SCHEMA, "sequences": {}}
    try:
        manifest = load_json_hardened(path)
    except ValueError as exc:  # one line naming the file (dvcore.jsonio)
        raise ValueError(f"{exc}: unreadable manifest; remove it to start afresh") from None
    if manifest.get("schema") != MANIFEST_SCHEMA:
        raise ValueError(f"{path}: not a dropvision campaign manifest (schema {manifest.get('schema')!r})")
    return manifest


class ManifestWriter:
    """Rewrites manifest.json atomically, the same text as ``write_json`` gives, at a cost that
    grows with the entries that changed, not with all of them.

    ``to_json`` with an indent runs Python's pure-Python encoder: 50 ms for a manifest of 1000
    sequences, rewritten as sequences finish, would make the client a bottleneck at a few dozen
    workers. Each sequence's entry is encoded once, again only when it changed (compared with a
    copy of what was encoded), and the text is joined from the pieces.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self._pieces: dict[str, tuple[dict, str]] = {}

    def text(self, manifest: dict) -> str:
        """The manifest's JSON text, equal to ``to_json(manifest)`` ("sequences" last)."""
        seqs = manifest["sequences"]
        head = {k: v for k, v in manifest.items() if k != "sequences"}
        if not seqs or list(manifest)[-1] != "sequences":
            return to_json(manifest)
        pieces = []
        for sid, entry in seqs.items():
            known = self._pieces.get(sid)
            if known is None or known[0] != entry:
                body = to_json(entry).rstrip("\n").replace("\n", "\n    ")
                known = (copy.deepcopy(entry), f"    {json.dumps(str(sid))}: {body}")
                self._pieces[sid] = known
            pieces.append(known[1])
        head_text = to_json(head).rstrip("\n")
        if not head_text.endswith("\n}"):  # never: the head holds the schema and the root
            return to_json(manifest)
        return head_text[:-2] + ',\n  "sequences": {\n' + ",\n".join(pieces) + "\n  }\n}\n"

    def write(self, manifest: dict) -> None:
        """Rewrite the manifest file atomically."""
        write_bytes(self.path, self.text(manifest).encode("utf-8"))


def _write_manifest(writer: ManifestWriter, manifest: dict) -> None:
    """Every manifest rewrite of `run_campaign` goes through here (one place to observe them)."""
    writer.write(manifest)


def _shard_is_current(shard: Path, digest: str, kind: str = "sequence") -> bool:
    try:
        summary = load_json_hardened(shard / "summary.json")
    except ValueError:
        return False
    return summary.get("input_hash") == digest and (shard / "frames.parquet").exists() and (
        kind != "shots" or (shard / "shots.parquet").exists())


# ----------------------------------------------------------------------------- driver
def _is_campaign_dataset(folder: Path) -> bool:
    """A dataset folder written by an older dropvision (before ownership markers): it holds
    our manifest."""
    try:
        return _load_manifest(folder / "manifest.json").get("schema") == MANIFEST_SCHEMA and (
            folder / "manifest.json").exists()
    except ValueError:
        return False


def run_campaign(
    root,
    dataset_dir,
    *,
    config=None,
    workers: int | None = None,
    dask_local: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    rerun_options=None,
    overwrite: bool = False,
    overrides: dict | None = None,
    labels: dict | None = None,
) -> CampaignResult:
    """Measure every sequence below ``root`` into the dataset folder ``dataset_dir``.

    Parameters
    ----------
    root : path
        Campaign root; every folder below it holding a sequence.json is a sequence.
    dataset_dir : path
        Output dataset folder (created; re-running resumes).
    config : MeasureConfig, optional
        Measurement configuration (part of each input hash).
    workers, dask_local, scheduler
        Where to run: see `dropvision.app.executors.make_executor`.
    progress : bool
        Show a progress bar.
    rerun_options : dropvision.app.rerun_log.RerunOptions, optional
        Log every sequence to Rerun: ``FILE.rrd`` becomes ``FILE-<sequence>.rrd`` per
        sequence (or all stream to one live viewer).
    overwrite : bool
        Write into an existing ``dataset_dir`` that holds files we did not write (they are
        kept; ours of the same names are replaced).
    overrides, labels : dict, optional
        Values of sequence.json keys for every sequence (options; part of each input hash),
        and how they were given: see `dropvision.io.sequence.open_sequence`.

    Raises
    ------
    dvcore.atomic.OutputError
        ``dataset_dir`` is a sequence folder, lies inside one or contains one, or holds files
        we did not write (without ``overwrite``); the Rerun recording lies inside a sequence
        folder.
    CampaignFailed
        Every sequence failed (none measured or unchanged): no dataset is written, the manifest
        records the errors.
    """
    check_executor_args(workers, dask_local=dask_local, scheduler=scheduler)  # before touching dataset_dir
    given = check_overrides(overrides, labels)  # a bad option: refused before any work
    config = config or MeasureConfig()
    if workers != 1 or dask_local is not None or scheduler is not None:
        # one process per core already: no threads inside a worker (no oversubscription)
        config = dataclasses.replace(config, workers=1)
    root, dataset_dir = Path(root), Path(dataset_dir)
    kinds = dict(find_inputs(root, overrides))
    folders = list(kinds)
    if not folders:
        raise FileNotFoundError(f"{root}: no sequence (folder with sequence.json) nor shot folder (images with no "
                                "delay to tell) found")
    # a recording inside a sequence folder would change its input hash (and the campaign's resume)
    check_outside_inputs(folders, None if rerun_options is None else rerun_options.path)
    n_shot_folders = sum(1 for k in kinds.values() if k == "shots")
    if rerun_options is not None and n_shot_folders:
        warnings.warn(f"--rerun: the {n_shot_folders} shot folder(s) are not logged to Rerun (sequences only)",
                      stacklevel=2)
    claim_dir(dataset_dir, inputs=folders, overwrite=overwrite, kind="campaign-dataset",
              is_ours=_is_campaign_dataset)
    with output_lock(dataset_dir):  # no other run writes it (nor cleans up its temporaries)
        for folder in (dataset_dir, dataset_dir / "shards"):
            remove_leftovers(folder)
        manifest_path = dataset_dir / "manifest.json"
        old = _load_manifest(manifest_path).get("sequences", {})
        # threads do not change results; options do
        config_repr = repr(dataclasses.replace(config, workers=0)) + (f" {sorted(given.items())!r}" if given else "")
        # the previous run's entries of the current sequences stay until each is looked at again, so
        # that a run stopped part-way never loses a finished sequence from the manifest
        current = [sequence_id(root, f) for f in folders]
        entries: dict[str, dict] = {sid: old[sid] for sid in current if sid in old}
        manifest = {"schema": MANIFEST_SCHEMA, "root": str(root.resolve()), "versions": software_versions(),
                    "sequences": entries}
        if rerun_options is not None:
            rerun_options = rerun_options.start_viewer()  # a viewer that cannot start: warned, work goes on
            if not rerun_options.enabled:
                rerun_options = None
        run = _CampaignRun(dataset_dir, entries, manifest, ManifestWriter(manifest_path),
                           tqdm(total=len(folders), desc="measuring sequences", unit="seq", disable=not progress))
        run.save()

        def tasks():
            """The sequences to measure, found lazily: a previous run's sequences are hashed (to
            know whether to skip them) while the workers measure those before them."""
            for sid, folder in zip(current, folders):
                shots = kinds[folder] == "shots"
                # a shot folder: its own files (not its sub-folders'), its kind part of the hash
                repr_ = config_repr + " shots" if shots else config_repr
                if not run.unchanged(sid, folder, old.get(sid, {}), kinds[folder], repr_):
                    yield sid, (measure_shots_to_shard if shots else measure_to_shard, str(folder),
                                str(dataset_dir / "shards" / shard_name(sid)), config,
                                None if rerun_options is None or shots else rerun_options.for_sequence(sid),
                                given or None, labels, repr_, sid)

        run.measure(tasks(), lambda: make_executor(workers, dask_local=dask_local, scheduler=scheduler))
        run.bar.close()
        if not run.result.measured and not run.result.skipped:
            # nothing measured: no empty dataset passed off as a result (the manifest keeps the errors)
            run.save()
            raise CampaignFailed(run.result, root)
        assemble_dataset(dataset_dir, entries, run.parts)
        run.save()
        return run.result


@dataclass
class _CampaignRun:
    """One campaign run's state while its sequences are measured: the manifest's entries (rewritten
    after every batch of finished sequences: a kill loses nothing), the result, the dataset parts
    read so far, the progress bar."""

    dataset_dir: Path
    entries: dict
    manifest: dict
    writer: ManifestWriter
    bar: tqdm
    result: CampaignResult = None
    parts: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.result is None:
            self.result = CampaignResult(dataset_dir=self.dataset_dir)

    def save(self) -> None:
        _write_manifest(self.writer, self.manifest)

    def unchanged(self, sid: str, folder: Path, prev: dict, kind: str, repr_: str) -> bool:
        """A sequence measured before with the same inputs and options: kept, its part read. Else
        its entry becomes pending (its worker computes the input hash) and False is returned."""
        digest = None
        if prev.get("status") == "ok" and prev.get("kind", "sequence") == kind:
            digest = input_hash(folder, repr_, recursive=False) if kind == "shots" else input_hash(folder, repr_)
        shard = shard_name(sid)
        if digest is not None and prev.get("input_hash") == digest and _shard_is_current(
            self.dataset_dir / "shards" / shard, digest, kind
        ):
            self.entries[sid] = prev
            self.result.skipped.append(sid)
            self.read_part(sid)
            self.bar.update(1)
            return True
        self.entries[sid] = {"path": str(folder.resolve()), "input_hash": digest, "shard": shard,
                             "status": "pending", "error": None}
        if kind == "shots":
            self.entries[sid]["kind"] = "shots"
        return False

    def read_part(self, sid: str) -> None:
        """Read an ok shard's share of the dataset now, while the workers measure the others
        (the final assembly then only concatenates). A shard that cannot be read is left to
        the final assembly, which reports it as before."""
        try:
            part = shard_part(self.dataset_dir, sid, self.entries[sid])
        except Exception:  # noqa: BLE001 - raised again, with its message, by assemble_dataset
            return
        if part is not None:
            self.parts[sid] = part
        elif self.entries[sid].get("status") == "failed":  # measured, but no row of the dataset (it says why)
            for done in (self.result.measured, self.result.skipped):
                if sid in done:
                    done.remove(sid)
            self.result.failed[sid] = self.entries[sid].get("error")

    def record(self, future, sid: str) -> None:
        """One finished sequence into the manifest's entries (the caller then rewrites the
        manifest)."""
        try:
            out = future.result()
        except Exception as exc:  # noqa: BLE001 - worker crash: record, go on
            out = {"status": "failed", "error": f"{type(exc).__name__}: {exc}", "meta": None}
        if out.get("warnings"):
            self.result.warnings[sid] = out["warnings"]
        part = out.get("part")
        self.entries[sid].update({k: v for k, v in out.items() if k not in ("warnings", "part")})
        if out["status"] == "ok":
            self.result.measured.append(sid)
            if part is not None and part.input_hash == self.entries[sid].get("input_hash"):
                self.parts[sid] = part  # read by the worker
            else:
                self.read_part(sid)
        else:
            self.result.failed[sid] = out["error"]
        self.bar.update(1)

    def measure(self, tasks, new_executor) -> None:
        """Submit every task ``(sid, (fn, folder, shard_dir, *args))`` and record each result (the
        worker gets the entry's input hash, None where it must compute it, after ``shard_dir``).

        The client's serial work per sequence is kept far below a task's time, so that many
        workers are not held up by it (tools/bench_campaign.py --overheads): a new sequence is
        submitted at once and its worker computes the input hash (the client only hashes sequences
        measured before, to know whether to skip them); finished sequences are recorded in
        batches, all that finished since the last manifest rewrite, with one rewrite per batch;
        each finished shard is read into its dataset part at once (`shard_part`). The executor
        starts only when a sequence needs measuring."""
        with contextlib.ExitStack() as stack:
            executor = None
            pending = {}

            def drain() -> None:
                while pending:
                    done = _wait_bounded(executor, pending)
                    for future in sorted(done, key=pending.get):
                        self.record(future, pending.pop(future))
                    self.save()

            for sid, (fn, folder, shard_dir, *rest) in tasks:
                if executor is None:
                    executor = stack.enter_context(new_executor())
                    stack.callback(drain)  # on an error below too, before the executor closes
                if isinstance(executor, SerialExecutor):
                    self.save()  # the sequence being measured, as pending
                future = executor.submit(fn, folder, shard_dir, self.entries[sid]["input_hash"], *rest)
                if future.done():  # the serial executor finishes inside submit
                    self.record(future, sid)
                    self.save()
                else:
                    pending[future] = sid
            self.save()  # every sequence submitted, as pending or done
            drain()


def parse_range(text: str, name: str) -> list[float]:
    """Parse ``start:stop:step`` (inclusive stop) or a comma list into values."""
    try:
        if ":" in text:
            start, stop, step = (float(x) for x in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            n = int(math.floor((stop - start) / step + 1e-9)) + 1
            return [round(start + i * step, 9) for i in range(n)]
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"{name}: expected start:stop:step (e.g. 50:80:5) or a comma list, got {text!r}") from None


def _synth_task(out_dir: str, u1: float, u2: float, seed: int, overrides: dict, overwrite: bool) -> str:
    config = SynthConfig(u1_um_per_ms=u1, u2_um=u2, seed=seed, **overrides)
    return str(write_synthetic_sequence(config, out_dir, progress=False, overwrite=overwrite))


def synth_campaign(out, u1_values, u2_values, *, repeats_per_point: int = 1, seed: int = 0, workers=None,
                   progress: bool = True, overrides: dict | None = None, overwrite: bool = False) -> list[Path]:
    """Render a campaign grid (like the paper's Table 1) of synthetic sequences with truth.

    ``out`` is created, or must be empty or ours (see `dvcore.atomic.claim_dir`); with
    ``overwrite`` an existing folder is written into and its same-named sequence folders are
    replaced as a whole.
    """
    check_executor_args(workers)  # before the output folder is touched
    out = claim_dir(out, overwrite=overwrite, kind="synthetic-campaign")
    with output_lock(out):
        return _synth_jobs(out, u1_values, u2_values, repeats_per_point, seed, workers, progress, overrides, overwrite)


def _synth_jobs(out: Path, u1_values, u2_values, repeats_per_point: int, seed: int, workers, progress: bool,
                overrides: dict | None, overwrite: bool) -> list[Path]:
    """The sequences of `synth_campaign` (``out`` claimed and locked)."""
    jobs = []
    for i, (u1, u2) in enumerate((a, b) for a in u1_values for b in u2_values):
        for r in range(repeats_per_point):
            name = f"u1_{u1:g}_u2_{u2:g}" + (f"_r{r}" if repeats_per_point > 1 else "")
            jobs.append((str(out / name), float(u1), float(u2), seed + 1000 * i + r))
    done = []
    with make_executor(workers) as executor:
        futures = [executor.submit(_synth_task, *job, dict(overrides or {}), overwrite) for job in jobs]
        for future in tqdm(as_completed(futures), total=len(futures), desc="rendering sequences", unit="seq", disable=not progress):
            done.append(Path(future.result()))
    return sorted(done)
