"""Campaign throughput: in-process vs a Dask LocalCluster of 1, 2, ... single-threaded workers.

    python tools/bench_campaign.py [--sequences 16] [--frames 181] [--size 320x1024]
                                   [--workers 1,2] [--rounds 3] [--keep DIR] [--profile] [--json FILE]

    # the scale-out figures of issue 12 (a 16-core machine):
    python tools/bench_campaign.py --workers 1,2,4,8,16 --sequences 64

    # what limits many workers, measured on a small machine (issue 22), and the projection:
    python tools/bench_campaign.py --overheads [--sequences 8] [--project 16,64] [--json FILE]

Renders a synthetic campaign once (``--sequences`` sequences of ``--frames`` delays 10 us
apart, frames ``--size`` W x H, `dropvision.synth`), then measures it into a fresh dataset
with each executor, every run in its own fresh process so that peak memory is per run:

- ``in-process``: ``run_campaign(workers=1)`` with one measuring thread (one core);
- ``dask-N``: a Dask ``LocalCluster(n_workers=N, threads_per_worker=1)`` started in the child,
  and ``run_campaign(scheduler=<its address>)``: the same path as
  ``dropvision campaign ROOT --out DS --scheduler tcp://HOST:8786`` on an existing cluster.
  The cluster's start-up is reported apart (``cluster s``), not in the throughput; the workers
  are fresh, so the first task on each pays the imports (``start s``, see below).

``--rounds`` rounds alternate the executors (round 1: in-process, dask-1, dask-2, ...; round 2:
the same again), so a load change on a shared machine hits every executor alike; medians are
reported: seconds, sequences/s, frames/s, efficiency vs dask-1 (``fps(N) / (N fps(1))``), peak
RSS of the main process and of the largest worker. From the Dask task stream: worker
utilisation (busy time of the workers / (N x wall time)), median seconds per task, and the
median time from the start of the run to each worker's first task (``start s``: input hashes,
connecting, and the imports a fresh worker does when it unpickles its first task). The
serial work in the main process (input hashes, manifest writes, dataset assembly) comes from a
cProfile of the run with ``--profile``.

``--overheads`` (one core is enough): times, one at a time, medians over the sequences,

- ``T``: one task (`measure_to_shard` in this process, one thread; it includes the
  sequence's input hash, which the worker computes);
- the client's serial work per sequence: one manifest rewrite (at this campaign's size and at
  ``--manifest-entries``; an upper bound: the client rewrites it once per batch of finished
  sequences), overlapping the tasks, and the final assembly that does not overlap anything
  (``S``: concatenating the parts, writing the tables); the input hash and the reading of
  the shard into its dataset part (`shard_part`) are timed apart: the worker does both (the
  client only for the sequences of a resumed run);
- ``o``: Dask's per-task overhead, from no-op tasks through a one-worker LocalCluster's
  executor (the path ``--scheduler`` takes), submitted all at once;
- the file-system I/O per task: bytes read (the sequence's files) and written (its shard).

and projects the efficiency at W workers (``--project``) for N sequences::

    c = client work per sequence (a manifest rewrite), overlapped with the tasks
    E(W) = N T / (W t(W)),  t(W) = S + max(ceil(N / W) (T + o), N c)

i.e. Amdahl's law with the non-overlapped serial part S, the per-task overhead o, and the client
as a server of rate 1/c that saturates at W = (T + o) / c workers. The I/O per task is given as
MB per task-second: W workers need W times that from a shared file system.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, os, resource, statistics, sys, time
mode, root, out, n, profile = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5] == "1"
t0 = time.perf_counter()
from dropvision.app.campaign import run_campaign
from dropvision.config import MeasureConfig
import_s = time.perf_counter() - t0
prof = None
if profile:
    import cProfile
    prof = cProfile.Profile()
res_extra = {"import_main_s": import_s}


def timed_run(**kw):
    global wall_start
    if prof is not None:
        prof.enable()
    wall_start = time.time()
    t = time.perf_counter()
    res = run_campaign(root, out, progress=False, **kw)
    dt = time.perf_counter() - t
    if prof is not None:
        prof.disable()
    return res, dt


if mode == "inprocess":
    res, dt = timed_run(workers=1, config=MeasureConfig(workers=1))
    worker_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    res_extra.update(cluster_s=0.0, utilisation=None, task_s=None, first_task_start_s=None)
else:
    from dask.distributed import Client, LocalCluster, get_task_stream
    t = time.perf_counter()
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    res_extra["cluster_s"] = time.perf_counter() - t
    with get_task_stream(client) as ts:
        res, dt = timed_run(scheduler=cluster.scheduler_address)
    worker_kb = max(client.run(lambda: __import__("resource").getrusage(__import__("resource").RUSAGE_SELF).ru_maxrss).values())
    spans = {}
    for task in ts.data:
        for s in task.get("startstops", ()):
            if s.get("action") == "compute":
                spans.setdefault(task["worker"], []).append((s["start"], s["stop"]))
    durs = sorted(b - a for v in spans.values() for a, b in v)
    busy = sum(durs)
    med = statistics.median(durs) if durs else float("nan")
    firsts = [min(v)[0] - wall_start for v in spans.values() if v]
    res_extra.update(utilisation=busy / (n * dt), task_s=med,
                     first_task_start_s=statistics.median(firsts) if firsts else None)
    client.close()
    cluster.close()
if prof is not None:
    import io, pstats
    buf = io.StringIO()
    st = pstats.Stats(prof, stream=buf)
    want = {"input_hash": "input hashes", "assemble_dataset": "dataset assembly", "write_json": "json writes", "_write_manifest": "manifest writes",
            "find_sequences": "finding sequences", "as_completed": "waiting for workers",
            "measure_to_shard": "measuring (in the main process)", "make_executor": "executor start/stop"}
    phases = {}
    for (file, line, func), (cc, nc, tt, ct, callers) in st.stats.items():
        if func in want and ("dropvision" in file or func == "as_completed"):
            phases[want[func]] = phases.get(want[func], 0.0) + ct
    res_extra["main_phases_s"] = phases
    st.sort_stats("cumulative").print_stats(25)
    res_extra["profile_text"] = buf.getvalue()
self_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"seconds": dt, "measured": len(res.measured), "failed": len(res.failed),
                  "peak_rss_main_mb": self_kb / 1024, "peak_rss_worker_mb": worker_kb / 1024, **res_extra}))
"""


def render(root: Path, sequences: int, frames: int, w: int, h: int) -> float:
    from dropvision.app.campaign import synth_campaign

    u1 = [50.0 + 30.0 * i / max(sequences - 1, 1) for i in range(sequences)]
    t0 = time.perf_counter()
    synth_campaign(root, u1, [25.0], progress=False,
                   overrides={"width_px": w, "height_px": h, "axis_col": w / 2 - 0.4,
                              "delays_us": tuple(10.0 * i for i in range(frames))})
    return time.perf_counter() - t0


def run_one(mode: str, n: int, root: Path, out: Path, profile: bool = False, timeout: float = 1800.0) -> dict:
    shutil.rmtree(out, ignore_errors=True)  # a fresh dataset: resuming would skip everything
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    cmd = [sys.executable, "-c", CHILD, mode, str(root), str(out), str(n), "1" if profile else "0"]
    # its own session: a run past the timeout (a worker that cannot import, a hung cluster) is
    # ended with its Dask workers, never left behind
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ROOT,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise RuntimeError(f"{mode}-{n}: no result after {timeout:.0f} s (killed)") from None
    r = subprocess.CompletedProcess(cmd, proc.returncode, stdout, stderr)
    if r.returncode:
        raise RuntimeError(f"{mode} {n}: exit {r.returncode}\n{r.stderr[-4000:]}")
    res = json.loads(r.stdout.strip().splitlines()[-1])
    if res["failed"] or not res["measured"]:
        raise RuntimeError(f"{mode} {n}: {res['failed']} sequences failed, {res['measured']} measured")
    shutil.rmtree(out, ignore_errors=True)
    return res


def _median_s(fn, repeats: int = 5) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def _noop(x):
    return x


def dask_task_overhead_s(tasks: int = 200) -> float | None:
    """Seconds per no-op task through a one-worker, one-thread LocalCluster's executor
    (submitted all at once, as run_campaign does); None without Dask."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        return None
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        ex = client.get_executor(pure=False)
        [f.result() for f in [ex.submit(_noop, i) for i in range(20)]]  # warm up
        t = time.perf_counter()
        futures = [ex.submit(_noop, i) for i in range(tasks)]
        from concurrent.futures import as_completed
        for f in as_completed(futures):
            f.result()
        return (time.perf_counter() - t) / tasks


def overheads(root: Path, work: Path, manifest_entries: int, project: list[int]) -> dict:
    """The figures of ``--overheads`` (see the module docstring), printed and returned."""
    import dataclasses

    from dropvision.app import campaign as cp
    from dropvision.config import MeasureConfig

    folders = cp.find_sequences(root)
    config = MeasureConfig(workers=1)
    config_repr = repr(dataclasses.replace(config, workers=0))
    out = work / "overheads_dataset"
    shutil.rmtree(out, ignore_errors=True)
    (out / "shards").mkdir(parents=True)
    task_s, hash_s, part_s, read_b, written_b, entries, parts = [], [], [], [], [], {}, {}
    cp.measure_to_shard(str(folders[0]), str(out / "shards" / "warm"), "x", config)  # imports, caches
    shutil.rmtree(out / "shards" / "warm")
    for folder in folders:
        sid = cp.sequence_id(root, folder)
        t = time.perf_counter()
        digest = cp.input_hash(folder, config_repr)
        hash_s.append(time.perf_counter() - t)
        shard = cp.shard_name(sid)
        t = time.perf_counter()
        res = cp.measure_to_shard(str(folder), str(out / "shards" / shard), None, config, config_repr=config_repr,
                                  seq_id=sid)
        task_s.append(time.perf_counter() - t)
        if res["status"] != "ok":
            raise RuntimeError(f"{folder}: {res['error']}")
        entries[sid] = {"path": str(folder), "input_hash": digest, "shard": shard, "status": "ok", "error": None,
                        "meta": res["meta"]}
        t = time.perf_counter()
        parts[sid] = cp.shard_part(out, sid, entries[sid])
        part_s.append(time.perf_counter() - t)
        read_b.append(sum(p.stat().st_size for p in folder.iterdir() if p.is_file()))
        written_b.append(sum(p.stat().st_size for p in (out / "shards" / shard).iterdir()))
    manifest = {"schema": cp.MANIFEST_SCHEMA, "root": str(root), "sequences": entries}
    def rewrite_s(doc: dict, name: str) -> float:
        """Median seconds of a manifest rewrite after one entry changed (as in a run)."""
        writer = cp.ManifestWriter(out / name)
        writer.write(doc)
        first = next(iter(doc["sequences"].values()))

        def one():
            first["status"] = "pending" if first["status"] == "ok" else "ok"
            writer.write(doc)
        return _median_s(one)

    manifest_s = rewrite_s(manifest, "manifest.json")
    one = next(iter(entries.values()))
    big = {"schema": cp.MANIFEST_SCHEMA, "root": str(root),
           "sequences": {f"s{i:06d}": dict(one) for i in range(manifest_entries)}}
    manifest_big_s = rewrite_s(big, "manifest_big.json")
    final_s = _median_s(lambda: cp.assemble_dataset(out, entries, parts), 3)
    # the same at --manifest-entries sequences (copies of these parts under new ids)
    big_entries, big_parts = {}, {}
    for i in range(manifest_entries):
        sid, entry = list(entries.items())[i % len(entries)]
        new = f"{sid}~{i:06d}"
        big_entries[new] = dict(entry)
        part = parts[sid]
        ts = part.timeseries.copy()
        ts["sequence_id"] = new
        big_parts[new] = dataclasses.replace(part, timeseries=ts, row=dict(part.row, sequence_id=new),
                                             meta=(new, *part.meta[1:]))
    final_big_s = _median_s(lambda: cp.assemble_dataset(out, big_entries, big_parts), 3)
    o = dask_task_overhead_s()
    med = statistics.median
    T, h, p, m = med(task_s), med(hash_s), med(part_s), manifest_s
    c = m  # the hash and the shard read are the worker's (the client does them on a resume only)
    n = len(folders)
    fig = {"sequences": n, "task_s": T, "hash_s": h, "manifest_write_s": m,
           f"manifest_write_s_at_{manifest_entries}": manifest_big_s, "shard_part_s": p,
           "client_per_sequence_s": c, "client_fraction": c / T, "final_assembly_s": final_s,
           f"final_assembly_s_at_{manifest_entries}": final_big_s, "dask_task_overhead_s": o,
           "read_bytes_per_task": med(read_b), "written_bytes_per_task": med(written_b),
           "io_mb_per_task_s": (med(read_b) + med(written_b)) / 1e6 / T}
    print(f"\none task T = {T:.3f} s (it includes the worker's input hash, {h * 1e3:.1f} ms, and reading its "
          f"shard back into its dataset part, {p * 1e3:.1f} ms); client per sequence c = {c * 1e3:.1f} ms = "
          f"{100 * c / T:.2f} % of T, at most (one manifest rewrite per finished sequence; one per batch when "
          f"several finish together; {manifest_entries} entries: {manifest_big_s * 1e3:.1f} ms), overlapped "
          "with the tasks")
    print(f"final assembly S = {final_s * 1e3:.1f} ms for {n} sequences, {final_big_s * 1e3:.0f} ms for "
          f"{manifest_entries} ({final_big_s / manifest_entries * 1e3:.2f} ms per sequence, "
          f"{100 * final_big_s / (manifest_entries * T):.3f} % of the task time)")
    print("Dask per-task overhead o = " + ("absent (no distributed)" if o is None else
                                          f"{o * 1e3:.2f} ms = {100 * o / T:.2f} % of T"))
    print(f"I/O per task: read {med(read_b) / 1e6:.1f} MB, written {med(written_b) / 1e6:.2f} MB = "
          f"{fig['io_mb_per_task_s']:.1f} MB per task-second")
    proj = []
    oo = o or 0.0
    for N in sorted({n, 64, 1000}):
        S_n = max(final_s + (final_big_s - final_s) * (N - n) / max(manifest_entries - n, 1), 0.0)
        # a manifest rewrite grows with the entries: interpolated between the two timed sizes
        c_n = max(m + (manifest_big_s - m) * (N - n) / max(manifest_entries - n, 1), 0.0)
        for W in project:
            t_w = S_n + max(math.ceil(N / W) * (T + oo), N * c_n)
            eff = N * T / (W * t_w)
            proj.append({"sequences": N, "workers": W, "seconds": t_w, "efficiency": eff,
                         "io_mb_s": W * fig["io_mb_per_task_s"]})
            print(f"  N = {N:5d}, W = {W:3d}: t = {S_n:.2f} + max({math.ceil(N / W)} x ({T:.3f} + {oo:.4f}), "
                  f"{N} x {c_n:.4f}) = "
                  f"{t_w:7.2f} s, E = {eff:.3f}; the file system must serve {W * fig['io_mb_per_task_s']:.0f} MB/s")
    fig["projection"] = proj
    shutil.rmtree(out, ignore_errors=True)
    return fig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=16)
    ap.add_argument("--frames", type=int, default=181, help="delays per sequence, 10 us apart (default 181)")
    ap.add_argument("--size", default="320x1024", help="frame size WxH (default 320x1024)")
    ap.add_argument("--workers", default="1,2", help="Dask worker counts, comma-separated (default 1,2)")
    ap.add_argument("--rounds", type=int, default=3, help="alternated rounds (medians; default 3)")
    ap.add_argument("--no-inprocess", action="store_true", help="skip the in-process executor")
    ap.add_argument("--no-dask", action="store_true", help="only the in-process executor")
    ap.add_argument("--profile", action="store_true",
                    help="after the rounds, one cProfiled run of the largest worker count: main-process phases")
    ap.add_argument("--keep", type=Path, default=None, help="render into this folder (reused if it exists)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds allowed per run (default 1800)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures here")
    ap.add_argument("--overheads", action="store_true",
                    help="measure task time, client serial work, Dask per-task overhead and I/O per task, "
                         "and project the efficiency at --project workers (see the module docstring)")
    ap.add_argument("--project", default="16,64", help="worker counts of the --overheads projection")
    ap.add_argument("--manifest-entries", type=int, default=1000,
                    help="--overheads: also time a manifest rewrite with this many sequences")
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.size.lower().split("x"))
    counts = sorted({int(x) for x in args.workers.split(",") if x.strip()})
    if any(c < 1 for c in counts):
        ap.error("--workers: counts must be >= 1")
    tmp = tempfile.TemporaryDirectory(prefix="bench_campaign_")
    work = args.keep or Path(tmp.name)
    root = work / f"campaign_{args.sequences}x{args.frames}_{w}x{h}"
    if not (root / ".dropvision-output.json").exists():
        shutil.rmtree(root, ignore_errors=True)
        dt = render(root, args.sequences, args.frames, w, h)
        print(f"rendered {args.sequences} sequences of {args.frames} frames ({w}x{h}) in {dt:.1f} s", flush=True)
    if args.overheads:
        load = os.getloadavg()
        print(f"{os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}", flush=True)
        fig = overheads(root, work, args.manifest_entries, [int(x) for x in args.project.split(",") if x.strip()])
        fig["load_before"], fig["load_after"] = load, os.getloadavg()
        if args.json:
            args.json.write_text(json.dumps(fig, indent=2))
        tmp.cleanup()
        return 0
    configs = ([] if args.no_inprocess else [("inprocess", 1)]) + ([] if args.no_dask else [("dask", c) for c in counts])
    if not configs:
        ap.error("nothing to run")
    load = os.getloadavg()
    print(f"{os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; "
          f"{args.rounds} alternated rounds of {', '.join(f'{m}-{n}' if m == 'dask' else m for m, n in configs)}", flush=True)
    runs: dict[tuple, list[dict]] = {c: [] for c in configs}
    for r in range(args.rounds):
        for mode, n in configs:
            res = run_one(mode, n, root, work / f"dataset_{mode}{n}", timeout=args.timeout)
            runs[(mode, n)].append(res)
            print(f"  round {r + 1} {mode}-{n}: {res['seconds']:.2f} s", flush=True)
    frames = args.frames * args.sequences
    med = statistics.median
    rows = []
    ref = None
    for mode, n in configs:
        rs = runs[(mode, n)]
        secs = med(x["seconds"] for x in rs)
        row = {"executor": "in-process" if mode == "inprocess" else f"dask-{n}", "workers": n, "seconds": secs,
               "seconds_all": [x["seconds"] for x in rs], "seq_per_s": args.sequences / secs,
               "frames_per_s": frames / secs, "peak_rss_main_mb": med(x["peak_rss_main_mb"] for x in rs),
               "peak_rss_worker_mb": med(x["peak_rss_worker_mb"] for x in rs),
               "cluster_s": med(x["cluster_s"] for x in rs)}
        for k in ("utilisation", "task_s", "first_task_start_s"):
            vals = [x[k] for x in rs if x.get(k) is not None]
            row[k] = med(vals) if vals else None
        if mode == "dask" and n == 1:
            ref = row["frames_per_s"]
        rows.append(row)
    for row in rows:
        row["efficiency"] = (row["frames_per_s"] / (row["workers"] * ref)
                             if ref and row["executor"].startswith("dask") else None)

    def f(v, fmt):
        return format(v, fmt) if v is not None else "-".rjust(len(format(0.0, fmt)))

    print()
    print(f"{args.sequences} sequences x {args.frames} frames ({w}x{h}) = {frames} frames; medians of {args.rounds}")
    print(f"{'executor':>10s} {'seconds':>8s} {'seq/s':>7s} {'frames/s':>9s} {'eff.':>6s} {'util.':>6s} "
          f"{'task s':>7s} {'start s':>8s} {'cluster s':>9s} {'RSS main MB':>11s} {'RSS worker MB':>13s}")
    for row in rows:
        print(f"{row['executor']:>10s} {row['seconds']:8.2f} {row['seq_per_s']:7.2f} {row['frames_per_s']:9.0f} "
              f"{f(row['efficiency'], '6.2f')} {f(row['utilisation'], '6.2f')} {f(row['task_s'], '7.3f')} "
              f"{f(row['first_task_start_s'], '8.2f')} {row['cluster_s']:9.2f} {row['peak_rss_main_mb']:11.0f} "
              f"{row['peak_rss_worker_mb']:13.0f}")
    result = {"sequences": args.sequences, "frames_per_sequence": args.frames, "size": [w, h],
              "rounds": args.rounds, "cores": os.cpu_count(), "load_before": load, "load_after": os.getloadavg(),
              "rows": rows}
    if args.profile:
        mode, n = configs[-1]
        res = run_one(mode, n, root, work / "dataset_profile", profile=True, timeout=args.timeout)
        print(f"\nprofile of one {mode}-{n} run ({res['seconds']:.2f} s), main process:")
        for k, v in sorted(res.get("main_phases_s", {}).items(), key=lambda kv: -kv[1]):
            print(f"  {k:32s} {v:7.2f} s")
        print(res.get("profile_text", ""))
        result["profile"] = {"executor": f"{mode}-{n}", "seconds": res["seconds"], "main_phases_s": res.get("main_phases_s")}
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
