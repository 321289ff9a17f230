"""Benchmark of the batched ECM Monte Carlo simulator (identify.montecarlo).

Target (issue): 10,000 ECM simulations of 200 samples in <= 20 ms on one core.
Reports, for N draws of the default synthetic ECM coefficients (1 % relative spread):

- modal form (batched cubic roots + residues),
- the batched time loop (numba if installed, and the numpy fallback),
- the exact scalar outputs at per-sample pinch-off / maximum-stroke instants,
- a per-system loop of identify.ecm.simulate (scipy expm + Python loop) on a small
  subset, extrapolated to N,

and the largest relative difference between the two simulators on that subset.

    .venv/bin/python tools/bench_montecarlo.py [--samples 10000] [--steps 200] [--subset 50]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def _best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--subset", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)

    from identify.dataset import default_physics
    from identify.ecm import EcmCoefficients, simulate
    from identify.montecarlo import HAVE_NUMBA, coeff_array, ecm_response_at, modal_form, simulate_ensemble
    from identify.waveform import Waveform

    try:
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    except (AttributeError, OSError):  # pragma: no cover
        pass
    c0 = coeff_array(default_physics().ecm_parameters().coefficients())
    rng = np.random.default_rng(0)
    C = c0 * (1 + 0.01 * rng.standard_normal((args.samples, 6)))
    w = Waveform(70.0, 25.0)
    t = np.arange(args.steps) * 10.0
    u = w.displacement_um(t - 220.0)
    simulate_ensemble(C[:2], t, u)  # compile numba outside the timing

    t_modal, modal = _best(lambda: modal_form(C), args.repeat)
    t_loop, (vol, flow) = _best(lambda: simulate_ensemble(modal, t, u), args.repeat)
    t_np, _ = _best(lambda: simulate_ensemble(modal, t, u, use_numba=False), max(1, args.repeat // 2))
    tau = 1050.0 - 220.0 + rng.standard_normal(args.samples)
    t_at, _ = _best(lambda: (ecm_response_at(modal, w, tau), ecm_response_at(modal, w, w.max_stroke_us)), args.repeat)

    sub = C[: args.subset]
    t0 = time.perf_counter()
    ref = [simulate(EcmCoefficients(*c), t, u) for c in sub]
    t_ref = (time.perf_counter() - t0) / len(sub) * args.samples
    err = max(np.abs(vol[i] - ref[i][0]).max() / np.abs(ref[i][0]).max() for i in range(len(sub)))

    n, m = args.samples, args.steps
    print(f"{n} ECM simulations x {m} samples, one core (numba {'yes' if HAVE_NUMBA else 'no'})")
    print(f"  modal form (roots + residues)     {1e3 * t_modal:8.2f} ms")
    print(f"  time loop ({'numba' if HAVE_NUMBA else 'numpy'})               {1e3 * t_loop:8.2f} ms")
    print(f"  total batched simulation          {1e3 * (t_modal + t_loop):8.2f} ms   (target <= 20 ms)")
    print(f"  time loop, numpy fallback         {1e3 * t_np:8.2f} ms")
    print(f"  exact outputs at pinch-off + max stroke (no time loop) {1e3 * t_at:8.2f} ms")
    print(f"  per-system scipy loop (extrapolated from {len(sub)})  {1e3 * t_ref:8.0f} ms  "
          f"-> speed-up x{t_ref / (t_modal + t_loop):.0f}")
    print(f"  max relative difference to identify.ecm.simulate: {err:.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
