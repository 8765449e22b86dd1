"""BLAS threads: the identification methods with the BLAS on one thread against the BLAS's own default.

Times ``identify_hammerstein`` (the Pouliquen et al. 2013 backlash experiment, j = 4000 columns; median of
--runs) and one ``diagnose_model`` (a hidden backlash from the nominal model, --diagnose-samples samples) in
this process, once with threadpoolctl limiting the BLAS to one thread (what ``rig`` does: RIG_BLAS_THREADS=1,
the default) and once with the BLAS left at its default, and prints both side by side with the thread
counts threadpoolctl reports.

    .venv/bin/python benchmarks/blas_threads.py [--runs 20] [--diagnose-samples 1500] [--default-first]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import scipy.linalg  # noqa: F401  (loads scipy's own BLAS, so that threadpoolctl sees it)
from threadpoolctl import threadpool_info, threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from identify.cyclic_excitation import cyclic_random_excitation  # noqa: E402
from identify.discrepancy_cases import hidden_effect_record  # noqa: E402
from identify.hammerstein_subspace import DEFAULT_FUTURE_HORIZON, DEFAULT_PAST_HORIZON, identify_hammerstein  # noqa: E402
from identify.model_discrepancy import diagnose_model  # noqa: E402
from identify.border_lifting import PathNodes  # noqa: E402
from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash  # noqa: E402

NODES = PathNodes.uniform(-3.0, 3.0, 8)
HOLD = 100


def blas_threads() -> str:
    """'openblas 2 threads, openblas 2 threads': what threadpoolctl sees now."""
    return ", ".join(f"{info['internal_api']} {info['num_threads']}" for info in threadpool_info()
                     if info["user_api"] == "blas") or "no BLAS found"


def hammerstein_data(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    linear = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=1.0)
    u = cyclic_random_excitation(4000 + DEFAULT_PAST_HORIZON + DEFAULT_FUTURE_HORIZON - 1, -3.0, 3.0, HOLD, rng=rng)
    y = PlantModel((pouliquen2013_backlash(), linear)).simulate(u)
    return u, y + 0.05 * rng.standard_normal(u.size)


def measure(runs: int, diagnose_samples: int) -> tuple[float, float, str]:
    u, y = hammerstein_data(2013)
    identify_hammerstein(u, y, NODES, hold_samples=HOLD)  # warm-up (imports, caches)
    seconds = []
    for _ in range(runs):
        start = time.perf_counter()
        identify_hammerstein(u, y, NODES, hold_samples=HOLD)
        seconds.append(time.perf_counter() - start)
    record = hidden_effect_record(("backlash",), 1000, num_samples=diagnose_samples)
    start = time.perf_counter()
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad, record.sample_period_s,
                            record.nominal_model)
    diagnose_s = time.perf_counter() - start
    return float(np.median(seconds)), diagnose_s, f"{result.verdict}: {', '.join(result.missing_effects) or '-'}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="identify_hammerstein runs per setting (median)")
    parser.add_argument("--diagnose-samples", type=int, default=1500, help="samples of the diagnosed record")
    parser.add_argument("--default-first", action="store_true",
                        help="measure the BLAS default first (on a shared host, to see the load's drift)")
    args = parser.parse_args()
    print(f"host: {platform.node() or '?'}, {os.cpu_count()} cores, {platform.machine()}, Python "
          f"{platform.python_version()}, numpy {np.__version__}; BLAS as loaded: {blas_threads()}")
    rows = []
    settings = [("1 thread (rig's default, RIG_BLAS_THREADS=1)", 1), ("BLAS default (RIG_BLAS_THREADS=all)", None)]
    for setting, limit in (settings[::-1] if args.default_first else settings):
        with threadpool_limits(limits=limit, user_api="blas") if limit else contextlib.nullcontext():
            threads = blas_threads()
            hammerstein_s, diagnose_s, verdict = measure(args.runs, args.diagnose_samples)
        rows.append((setting, threads, hammerstein_s, diagnose_s, verdict))
    print(f"\n| BLAS threads | threadpoolctl sees | identify_hammerstein (median of {args.runs}) | diagnose "
          f"({args.diagnose_samples} samples, hidden backlash) | verdict |")
    print("|---|---|---|---|---|")
    for setting, threads, hammerstein_s, diagnose_s, verdict in rows:
        print(f"| {setting} | {threads} | {1e3 * hammerstein_s:.1f} ms | {diagnose_s:.2f} s | {verdict} |")


if __name__ == "__main__":
    main()
