"""Estimator benchmark: closed-form eq. 5 solve vs the paper's Levenberg-Marquardt.

Same 10 000 noisy samples (random stiffness 0.1-1 N/mm, pan/tilt within 15°, 7-9 mm advance,
0.3 px centroid noise at 12.7 px/mm) through

* ``solve_lm``     -- scipy least_squares(method="lm") on the 7 rows of eq. 5 (the baseline),
* ``solve_exact``  -- the closed form, one sample per call (what a node does per message),
* ``solve_batch``  -- the closed form vectorised over all samples,

plus vectorised Hertz (eq. 6) and thickness-corrected (eq. 7) moduli from ``models.contact``.
Targets: per sample >= 100x faster than LM, batch >= 1000x, identical answers. Ratios are
against the LM time measured in the same run. Prints a table, then one JSON line.

    .venv/bin/python bench/estimator.py [--n 10000]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from models.multi_indenter import CENTROID_NOISE_PX, PAPER_GEOMETRY, PX_PER_MM, forward  # noqa: E402
from models.multi_indenter_batch import solve_batch  # noqa: E402
from models.multi_indenter_solve import StiffnessSolution, solve_exact, solve_lm  # noqa: E402

T = TypeVar("T")


def make_samples(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4) noisy indenter displacements (mm), all four indenters in contact."""
    rng = np.random.default_rng(seed)
    out = np.empty((0, 4))
    while len(out) < n:
        m = 2 * n
        kt = np.exp(rng.uniform(math.log(0.1), math.log(1.0), m))
        pan, tilt = np.radians(rng.uniform(-15, 15, (2, m)))
        c = forward(PAPER_GEOMETRY, kt, rng.uniform(7.0, 9.0, m), pan, tilt)
        ok = c.contact.all(axis=1) & ~c.saturated.any(axis=1)
        dx = c.dx_mm[ok] + rng.normal(0, CENTROID_NOISE_PX / PX_PER_MM, (int(ok.sum()), 4))
        out = np.concatenate([out, dx])
    return out[:n]


def best_of(repeats: int, fn: Callable[[], T]) -> tuple[float, T]:
    """Shortest wall time (s) of ``repeats`` runs of ``fn``, and the last run's result."""
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def contact_rates(n: int) -> dict[str, float]:
    """Vectorised moduli per second from models.contact (empty if that module is missing)."""
    try:
        from models import contact
    except ImportError:
        return {}
    rng = np.random.default_rng(1)
    force, depth = rng.uniform(0.05, 2.0, n), rng.uniform(0.2, 3.0, n)
    rates: dict[str, float] = {}
    hertz = getattr(contact, "hertz_modulus", None) or getattr(contact, "e_hertz", None)
    corrected = getattr(contact, "corrected_modulus", None) or getattr(contact, "e_corrected", None)
    if hertz is not None:
        rates["hertz_e_per_s"] = n / best_of(5, lambda: hertz(force, depth, 4.0, 0.5))[0]
    if corrected is not None:
        rates["corrected_e_per_s"] = (
            n / best_of(5, lambda: corrected(force, depth, 4.0, 20.0, 0.5))[0]
        )
    return rates


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=10_000, help="samples (default 10000)")
    args = parser.parse_args()
    n = args.n
    dx = make_samples(n)
    rows = dx.tolist()  # what a node gets from a decoded message: lists of floats

    # LM and the single exact solve are timed chunk by chunk, interleaved, so that both see
    # the same load on a shared machine; best of 3 per chunk for both, garbage collector off
    # while timing (as in timeit).
    lm: list[StiffnessSolution] = []
    ex: list[StiffnessSolution] = []
    t_lm = t_exact = 0.0
    gc.disable()
    try:
        for start in range(0, n, 500):
            chunk = rows[start : start + 500]
            t, lm_chunk = best_of(3, lambda c=chunk: [solve_lm(r) for r in c])  # type: ignore[misc]
            t_lm += t
            t, ex_chunk = best_of(3, lambda c=chunk: [solve_exact(r) for r in c])  # type: ignore[misc]
            t_exact += t
            lm += lm_chunk
            ex += ex_chunk
        t_batch, batch = best_of(10, lambda: solve_batch(dx))
    finally:
        gc.enable()

    valid_lm = np.array([s.valid for s in lm])
    valid_ex = np.array([s.valid for s in ex])
    both = valid_lm & valid_ex
    k_lm = np.array([s.k_t_n_per_mm for s in lm])
    k_ex = np.array([s.k_t_n_per_mm for s in ex])
    ang_lm = np.array([(s.pan_rad, s.tilt_rad) for s in lm])
    ang_ex = np.array([(s.pan_rad, s.tilt_rad) for s in ex])
    max_dk = float(np.max(np.abs(k_lm - k_ex)[both])) if both.any() else math.nan
    max_rel_dk = float(np.max((np.abs(k_lm - k_ex) / k_ex)[both])) if both.any() else math.nan
    max_dang = float(np.max(np.abs(ang_lm - ang_ex)[both])) if both.any() else math.nan
    batch_same = bool(
        np.array_equal(batch.valid, valid_ex)
        and np.array_equal(batch.k_t_n_per_mm, k_ex, equal_nan=True)
        and np.allclose(batch.pan_rad, ang_ex[:, 0], rtol=1e-15, atol=0, equal_nan=True)
    )

    us = 1e6 / n
    r_exact, r_batch = t_lm / t_exact, t_lm / t_batch
    rates = contact_rates(1_000_000)
    agree = bool(np.array_equal(valid_lm, valid_ex) and max_rel_dk <= 1e-9 and max_dang <= 1e-9)
    print(f"estimator benchmark, {n} samples (valid: LM {valid_lm.sum()}, exact {valid_ex.sum()})")
    print(f"{'solver':<28}{'us/sample':>12}{'x faster than LM':>20}")
    print(f"{'LM (scipy, eq. 5)':<28}{t_lm * us:>12.2f}{1.0:>20.1f}")
    print(
        f"{'exact, one call per sample':<28}{t_exact * us:>12.3f}{r_exact:>20.1f}   target >= 100"
    )
    print(f"{'exact, batch (numpy)':<28}{t_batch * us:>12.4f}{r_batch:>20.0f}   target >= 1000")
    print(f"max |K_t exact - LM| = {max_dk:.3g} N/mm (relative {max_rel_dk:.3g}); "
          f"max |angle diff| = {max_dang:.3g} rad; same validity: {np.array_equal(valid_lm, valid_ex)}")  # fmt: skip
    print(f"batch identical to single solve: {batch_same}")
    for name, rate in rates.items():
        print(f"{name:<28}{rate:>12.3g} per s (vectorised, models.contact)")
    if not rates:
        print("models.contact not available: Hertz / corrected rates not measured")
    result = {
        "bench": "estimator",
        "n": n,
        "lm_us_per_sample": t_lm * us,
        "exact_us_per_sample": t_exact * us,
        "batch_us_per_sample": t_batch * us,
        "exact_speedup_vs_lm": r_exact,
        "batch_speedup_vs_lm": r_batch,
        "max_abs_diff_k_t_n_per_mm": max_dk,
        "max_rel_diff_k_t": max_rel_dk,
        "max_abs_diff_angle_rad": max_dang,
        "exact_agrees_with_lm": agree,
        "batch_identical_to_single": batch_same,
        **rates,
        "targets_met": bool(r_exact >= 100 and r_batch >= 1000 and agree and batch_same),
    }
    print(json.dumps(result))
    return 0 if agree and batch_same else 1


if __name__ == "__main__":
    sys.exit(main())
