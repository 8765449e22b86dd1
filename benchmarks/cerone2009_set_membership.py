"""Reproduce Section 6 of Cerone, Piga and Regruto (2009) and compare with their Tables I and II.

True γ = [0.248 0.0698 0.252 0.0349], θ = [0.5 0.7 1.4 0.8]; M = 50 steady-state amplitudes equally spaced
in [0.6, 3] through the staircase filtered with a = 0.8125; PRBS ±1 with N samples; uniform noise in
[-Δη, Δη] with Δη = 2π/2^n_bit. For every n_bit and Monte Carlo run both linear-block methods are run on
the same inner-signal bounds. Printed: medians over the runs of the central estimates and half-widths,
the fraction of runs whose bounds contain the true parameter, and the run time of the whole pipeline
(stages 1-3) per method.

Usage (from the repository root)::

    nice -n 10 .venv/bin/python benchmarks/cerone2009_set_membership.py --runs 100 --num-samples 100
    nice -n 10 .venv/bin/python benchmarks/cerone2009_set_membership.py --runs 20 --num-samples 1000

Scaling with the record length: ``--scaling N [N ...]`` runs the coupled method only, for every N
and n_bit, with run r of (N, n_bit) drawn from ``numpy.random.default_rng([seed, N, n_bit, r])`` (so one
failing case is rerun alone with ``--scaling N --n-bits n --first-run r --runs 1``), and prints wall and CPU
time (this process and its worker processes), peak memory, median half-widths, truth containment and the
outer/inner ratio (the median over the runs of each run's largest ratio, and the largest of all runs)::

    nice -n 10 .venv/bin/python benchmarks/cerone2009_set_membership.py --scaling 100 1000 10000 100000 \
        --runs 3 --jobs 2
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import time
from functools import partial

import numpy as np

from identify.excitation_design import filtered_staircase, prbs_sequence, staircase_steady_state_indices
from identify.feasible_parameter_set import bound_backlash_parameters
from identify.inner_signal_bounds import bound_inner_signal, shared_backlash_constraints
from identify.linear_block_bounds import DEFAULT_PARTITION_SAMPLES, bound_linear_block
from identify.plant_blocks import LinearBlock, OutputBacklash, PlantModel
from rig.batch import RenewingProcessPool

GAMMA = {"m_l": 0.248, "c_l": 0.0698, "m_r": 0.252, "c_r": 0.0349}
THETA = {"a1": 0.5, "a2": 0.7, "b1": 1.4, "b2": 0.8}
N_BITS = (15, 12, 10, 8)
# Table I: (γ^c, Δγ) per n_bit, in the order m_l, c_l, m_r, c_r
TABLE_I = {
    15: ((0.2481, 1.1e-4), (0.0702, 4.8e-4), (0.2520, 2.1e-5), (0.0349, 1.0e-4)),
    12: ((0.2474, 6.6e-4), (0.0678, 2.4e-3), (0.2521, 1.3e-4), (0.0354, 7.0e-4)),
    10: ((0.2503, 2.8e-3), (0.0825, 1.6e-2), (0.2513, 8.0e-4), (0.0306, 5.2e-3)),
    8: ((0.2475, 2.9e-3), (0.0655, 1.8e-2), (0.2615, 1.1e-2), (0.0625, 3.7e-2)),
}
# Table II (N = 100): SNR and (θ^c, Δθ) per n_bit, in the order a1, a2, b1, b2
TABLE_II = {
    15: (73.2, ((0.500, 4.3e-4), (0.700, 2.5e-4), (1.400, 4.3e-4), (0.800, 7.2e-4))),
    12: (56.2, ((0.500, 4.8e-3), (0.700, 2.8e-3), (1.400, 8.7e-3), (0.800, 1.0e-2))),
    10: (43.0, ((0.503, 1.8e-2), (0.698, 1.9e-2), (1.400, 4.2e-2), (0.806, 4.6e-2))),
    8: (30.9, ((0.510, 6.9e-2), (0.706, 5.3e-2), (1.410, 1.1e-1), (0.805, 1.2e-1))),
}
METHODS = ("paper", "coupled")


def run_once(n_bit: int, num_samples: int, rng: np.random.Generator, staircase: np.ndarray, steady: np.ndarray,
             steady_w: np.ndarray, plant: PlantModel) -> dict:
    delta = 2.0 * np.pi / 2**n_bit
    steady_y = steady_w + rng.uniform(-delta, delta, steady.size)
    u = prbs_sequence(num_samples, 1.0, rng=rng)
    w = plant.simulate(u)
    noise = rng.uniform(-delta, delta, num_samples)
    y = w + noise
    started, started_cpu = time.perf_counter(), time.process_time()
    backlash = bound_backlash_parameters(staircase[steady], steady_y, delta)
    inner = bound_inner_signal(y, delta, backlash)
    stage12_s, stage12_cpu_s = time.perf_counter() - started, time.process_time() - started_cpu
    out = {"gamma": backlash.intervals(), "snr_db": 10 * np.log10(np.sum(w**2) / np.sum(noise**2)),
           "invertible": inner.num_invertible}
    for method in METHODS:
        started, started_cpu = time.perf_counter(), time.process_time()
        shared = shared_backlash_constraints(y, delta, backlash, inner) if method == "coupled" else None
        linear = bound_linear_block(u, inner.lower_rad, inner.upper_rad, na=2, nk=1, nb=2, method=method,
                                    shared_backlash=shared)
        out[method] = linear.intervals
        if method == "coupled":
            out["inner_gap"] = max((linear.intervals[k].upper - linear.intervals[k].lower)
                                   / max(linear.inner_upper[k] - linear.inner_lower[k], 1e-300) for k in THETA)
        out[method + "_time"] = stage12_s + time.perf_counter() - started
        out[method + "_cpu"] = stage12_cpu_s + time.process_time() - started_cpu
        out[method + "_lps"] = linear.num_linear_programs
    return out


def _cpu_s() -> float:
    """CPU seconds of this process and of its (finished or running-pool) children so far."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _pool_cpu_s(pool: RenewingProcessPool | None) -> float:
    """CPU seconds of the live worker processes (RUSAGE_CHILDREN counts them only once they exit; a worker that
    died is not counted)."""
    if pool is None:
        return 0.0
    total = 0.0
    for pid in (process.pid for process in pool.processes()):
        try:
            with open(f"/proc/{pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError):
            pass
    return total


def scaling(args: argparse.Namespace) -> None:
    backlash = OutputBacklash(GAMMA["m_l"], GAMMA["c_l"], GAMMA["m_r"], GAMMA["c_r"])
    plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), backlash))
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    steady_w = plant.simulate(staircase)[steady]
    # the pool of `rig identify output-backlash --jobs N`: a lost worker's tasks are solved again on a new pool
    pool = RenewingProcessPool(args.jobs) if args.jobs > 1 else None
    map_windows = map if pool is None else partial(pool.map, chunksize=4)
    print(f"Coupled bounds against the record length: seed {args.seed}, run r of (N, n_bit) from "
          f"default_rng([{args.seed}, N, n_bit, r]); {args.jobs} process(es) for the windows, joint_samples "
          f"{args.joint_samples}, partition_samples {args.partition_samples}, moment_samples {args.moment_samples}, "
          f"{'windows and parts' if args.windows else 'trajectory relaxation where the record allows'}, "
          f"{os.cpu_count()} cores; medians over the "
          "runs")
    header = (f"{'N':>6} {'n_bit':>5} {'runs':>4} | {'wall s':>7} {'max':>7} {'CPU s':>7} {'peak MiB':>8} | "
              + " ".join(f"{'D' + name:>9}" for name in THETA) + f" | {'in':>4} {'out/inner':>9} {'max':>5} | windowing")
    print(header)
    for num_samples in args.scaling:
        for n_bit in args.n_bits:
            rows = []
            for run in range(args.first_run, args.first_run + args.runs):
                rng = np.random.default_rng([args.seed, num_samples, n_bit, run])
                delta = 2.0 * np.pi / 2**n_bit
                steady_y = steady_w + rng.uniform(-delta, delta, steady.size)
                u = prbs_sequence(num_samples, 1.0, rng=rng)
                y = plant.simulate(u) + rng.uniform(-delta, delta, num_samples)
                started, cpu = time.perf_counter(), _cpu_s() + _pool_cpu_s(pool)
                backlash = bound_backlash_parameters(staircase[steady], steady_y, delta)
                inner = bound_inner_signal(y, delta, backlash)
                shared = shared_backlash_constraints(y, delta, backlash, inner)
                linear = bound_linear_block(u, inner.lower_rad, inner.upper_rad, na=2, nk=1, nb=2, method="coupled",
                                            shared_backlash=shared, map_windows=map_windows,
                                            joint_samples=args.joint_samples,
                                            partition_samples=args.partition_samples,
                                            moment_samples=args.moment_samples,
                                            verify_inner=num_samples <= args.inner_max,
                                            eliminate_inner_signal=not args.windows)
                wall = time.perf_counter() - started
                cpu = _cpu_s() + _pool_cpu_s(pool) - cpu
                ratio = math.nan
                if linear.inner_lower is not None:
                    ratio = max((linear.intervals[k].upper - linear.intervals[k].lower)
                                / max(linear.inner_upper[k] - linear.inner_lower[k], 1e-300) for k in THETA)
                rows.append({"wall": wall, "cpu": cpu, "half": [linear.intervals[k].half_width for k in THETA],
                             "in": all(linear.intervals[k].contains(v) for k, v in THETA.items()), "ratio": ratio,
                             "windowing": linear.windowing, "notes": linear.notes})
            half = np.median([r["half"] for r in rows], axis=0)
            ratios = [r["ratio"] for r in rows if math.isfinite(r["ratio"])]
            print(f"{num_samples:>6} {n_bit:>5} {len(rows):>4} | {np.median([r['wall'] for r in rows]):>7.2f} "
                  f"{max(r['wall'] for r in rows):>7.2f} {np.median([r['cpu'] for r in rows]):>7.2f} "
                  f"{_peak_mib():>8.0f} | " + " ".join(f"{h:>9.3e}" for h in half)
                  + f" | {np.mean([r['in'] for r in rows]):>4.0%} "
                  + (f"{np.median(ratios):>9.2f}" if ratios and np.median(ratios) < 100 else
                     f"{'>100' if ratios else '-':>9}")
                  + (f" {max(ratios):>5.2f}" if ratios and max(ratios) < 100 else f" {'>100' if ratios else '-':>5}")
                  + f" | {rows[-1]['windowing']}",
                  flush=True)
            for r in rows:
                for note in r["notes"]:
                    print(f"{'':>6} note: {note}")
    if pool is not None:
        pool.shutdown()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(f"(peak MiB: the largest resident set of this process so far; CPU: this process and its window workers; "
          f"load average at the end {load:.2f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per n_bit (default 100)")
    parser.add_argument("--num-samples", type=int, default=100, help="N of the PRBS experiment (default 100)")
    parser.add_argument("--n-bits", type=int, nargs="+", default=list(N_BITS))
    parser.add_argument("--seed", type=int, default=2009)
    parser.add_argument("--scaling", type=int, nargs="+", metavar="N", default=None,
                        help="coupled method only, for each record length N (see the module docstring)")
    parser.add_argument("--first-run", type=int, default=0, help="--scaling: index of the first run (default 0)")
    parser.add_argument("--jobs", type=int, default=1, help="--scaling: processes for the windows (default 1)")
    parser.add_argument("--joint-samples", type=int, default=3000, help="--scaling: joint_samples (default 3000)")
    parser.add_argument("--partition-samples", type=int, default=DEFAULT_PARTITION_SAMPLES,
                        help="--scaling: partition of the box of a up to this N (default "
                             f"{DEFAULT_PARTITION_SAMPLES}; 0: off)")
    parser.add_argument("--moment-samples", type=int, default=0,
                        help="--scaling: cuts from the moment (SDP) relaxation with cvxpy up to this N (default 0: off)")
    parser.add_argument("--windows", action="store_true",
                        help="--scaling: bound by windows and joint parts with δx as columns instead of the trajectory "
                             "relaxation (eliminate_inner_signal=False)")
    parser.add_argument("--inner-max", type=int, default=10000,
                        help="--scaling: verified inner values (outer/inner) only up to this N (default 10000)")
    args = parser.parse_args()
    if args.scaling is not None:
        scaling(args)
        return

    backlash = OutputBacklash(GAMMA["m_l"], GAMMA["c_l"], GAMMA["m_r"], GAMMA["c_r"])
    plant = PlantModel((LinearBlock((0.5, 0.7), (0.0, 1.4, 0.8), 1.0), backlash))
    staircase = filtered_staircase(list(np.linspace(0.6, 3.0, 50)), 0.8125, 100)
    steady = staircase_steady_state_indices(50, 100)
    steady_w = plant.simulate(staircase)[steady]
    rng = np.random.default_rng(args.seed)

    results = {}
    for n_bit in args.n_bits:
        results[n_bit] = [run_once(n_bit, args.num_samples, rng, staircase, steady, steady_w, plant)
                          for _ in range(args.runs)]

    print(f"Cerone, Piga, Regruto (2009), Section 6: {args.runs} Monte Carlo runs per n_bit, N = {args.num_samples}, "
          f"M = 50, seed {args.seed}; medians over the runs; 'in' = fraction of runs whose bounds contain the truth")
    print()
    print("Table I (backlash, exact orthotope of D_gamma)")
    print(f"{'n_bit':>5} {'param':>5} {'true':>7} | {'paper c':>8} {'paper D':>8} | {'ours c':>8} {'ours D':>8} {'in':>5}")
    for n_bit in args.n_bits:
        for k, name in enumerate(GAMMA):
            centers = np.median([r["gamma"][name].center for r in results[n_bit]])
            widths = np.median([r["gamma"][name].half_width for r in results[n_bit]])
            inside = np.mean([r["gamma"][name].contains(GAMMA[name]) for r in results[n_bit]])
            paper_c, paper_d = TABLE_I[n_bit][k]
            print(f"{n_bit:>5} {name:>5} {GAMMA[name]:>7.4f} | {paper_c:>8.4f} {paper_d:>8.1e} | "
                  f"{centers:>8.4f} {widths:>8.1e} {inside:>5.0%}")
    print()
    print(f"Table II (linear block, N = {args.num_samples}; the paper's Table II is for N = 100)")
    print(f"{'n_bit':>5} {'SNR':>5} {'param':>5} {'true':>5} | {'paper c':>7} {'paper D':>8} | "
          f"{'EIV c':>7} {'EIV D':>8} {'in':>5} | {'coupled c':>9} {'coupled D':>9} {'in':>5} {'II/coupled':>10}")
    for n_bit in args.n_bits:
        paper_snr, rows = TABLE_II[n_bit]
        snr = np.median([r["snr_db"] for r in results[n_bit]])
        for k, name in enumerate(THETA):
            cells = []
            for method in METHODS:
                centers = np.median([r[method][name].center for r in results[n_bit]])
                widths = np.median([r[method][name].half_width for r in results[n_bit]])
                inside = np.mean([r[method][name].contains(THETA[name]) for r in results[n_bit]])
                cells.append((centers, widths, inside))
            paper_c, paper_d = rows[k]
            (ec, ed, ein), (cc, cd, cin) = cells
            print(f"{n_bit:>5} {snr:>5.1f} {name:>5} {THETA[name]:>5.3f} | {paper_c:>7.3f} {paper_d:>8.1e} | "
                  f"{ec:>7.4f} {ed:>8.1e} {ein:>5.0%} | {cc:>9.5f} {cd:>9.1e} {cin:>5.0%} {paper_d / cd:>10.1f}")
        print(f"{'':>5} (paper's SNR {paper_snr} dB; median invertible samples "
              f"{np.median([r['invertible'] for r in results[n_bit]]):.0f} of {args.num_samples})")
    print()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    print(f"Whole pipeline time per run (stages 1-3, one process, N = {args.num_samples}), seconds: wall clock "
          f"(perf_counter) and CPU (process_time); load average at the end {load:.2f} on {os.cpu_count()} cores")
    print(f"{'n_bit':>5} | {'EIV median':>10} {'EIV max':>8} | {'coupled median':>14} {'coupled max':>11} "
          f"{'CPU median':>10} {'CPU max':>8} {'LPs':>4} {'outer/inner':>11}")
    for n_bit in args.n_bits:
        paper_times = [r["paper_time"] for r in results[n_bit]]
        coupled_times = [r["coupled_time"] for r in results[n_bit]]
        coupled_cpu = [r["coupled_cpu"] for r in results[n_bit]]
        lps = np.median([r["coupled_lps"] for r in results[n_bit]])
        gap = np.median([r["inner_gap"] for r in results[n_bit]])
        print(f"{n_bit:>5} | {np.median(paper_times):>10.3f} {np.max(paper_times):>8.3f} | "
              f"{np.median(coupled_times):>14.3f} {np.max(coupled_times):>11.3f} "
              f"{np.median(coupled_cpu):>10.3f} {np.max(coupled_cpu):>8.3f} {lps:>4.0f} {gap:>11.2f}")
    print("(outer/inner: median over runs of the largest ratio, over the parameters, of the coupled outer interval to "
          "the interval spanned by verified points of the exact feasible set; 1.00 = exact)")


if __name__ == "__main__":
    main()
