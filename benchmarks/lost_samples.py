"""Lost samples: what each identification method returns when a fraction of a record's samples is LOST, and
whether it still holds the truth.

Records are simulated with the truth known, their samples marked LOST as a run marks them in its log
(``rig/log_file.py``: the row stays with its time and command, the angle is ``nan``, the encoder count empty and
the flags column has the LOST bit), and the logs are given to the ``rig`` commands in this process, with their
JSON output read back (the same code path as a user's ``rig ... --json``):

(a) ``rig identify output-backlash`` (Cerone, Piga, Regruto 2009; coupled method, the default) on
    ``rig simulate configs/plants/cerone2009.toml`` with ``configs/experiments/steady_staircase.toml`` (10 000
    samples) and the shipped ``prbs.toml`` lengthened to 1000 samples (``num_samples``; in the shipped 100
    samples a fraction of 0.1 % is no sample at all). ``--partition-samples 0`` keeps the run short (the last
    tightening of the linear bounds; the guarantee does not depend on it). Truth: the plant config's
    m_l, c_l, m_r, c_r and a1, a2, b1, b2. Reported: whether every bound holds its true value, the widths of
    c_l and c_r, the largest ratio of a width to its width on the same record with nothing lost (backlash and
    linear parameters apart), the dynamic record's equations of eq. (7) left out, and the steady-state points
    taken before the end of their half-wave (the end sample LOST: the last usable sample of the settled tail
    is taken) or left out (the whole tail LOST: the command refuses the log).
(b) ``rig identify hammerstein`` (Pouliquen et al. 2013; all defaults: order auto, hold = the leading run) on
    ``rig simulate configs/plants/pouliquen2013_backlash.toml`` with ``configs/experiments/hammerstein_cyclic.toml``
    (4100 samples, coloured noise at 10 dB SNR). Border error: the RMS on [-3, 3] of both identified paths
    against the true ones, as ``benchmarks/pouliquen2013_hammerstein.py`` measures it (its ``true_paths``
    and ``GRID``), and its change from the same record with nothing lost; the Hankel columns (windows of
    p + f = 30 samples) left out because they hold a LOST sample (the method drops windows, not cycles).
(c) ``rig diagnose --model NOMINAL.toml`` (the model-discrepancy workflow) on a record of
    :func:`identify.discrepancy_cases.hidden_effect_record` with one hidden backlash (3000 samples, 12-bit
    encoder; the case ``benchmarks/model_discrepancy_confusion.py`` and the tests use), against its nominal
    linear model written as a plant TOML. Right: the verdict ``named`` with backlash the only effect named.
    Reported: the verdicts and names, how many of the intervals of the named backlash's c_l and c_r hold
    the true value, and their widths.

Rows: nothing lost, 0.1 %, 1 % and 5 % of each record's samples scattered at random, and 1 % in bursts of 50
consecutive samples (at least one burst per record; bursts do not overlap). Each record has
``round(fraction * N)`` samples LOST (at least one). Per seed S the records are simulated once (``rig
simulate --seed S``, ``hidden_effect_record(("backlash",), 1000 + S)``) and every row marks its own samples
LOST in copies of them, drawn by ``numpy.random.default_rng([S, row, record])``: the rows differ only in what
was lost. A refusal (exit code 2) is counted and its message listed with what was left; every wrong answer
(a true value outside a bound, an empty feasible set, a wrong name) is listed with its seed, row, the truth
and what came out, and so is every Hammerstein border error more than twice the same record's with nothing
lost.

Run:  OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/lost_samples.py [--seeds 5]
      [--quick] [--keep DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import io
import json
import os
import platform
import shlex
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from identify.discrepancy_cases import hidden_effect_record  # noqa: E402
from identify.effect_catalogue import effect  # noqa: E402
from identify.experiment_record import ExperimentMetadata, SampleFlag  # noqa: E402
from identify.plant_blocks import LinearBlock, OutputBacklash  # noqa: E402
from pouliquen2013_hammerstein import GRID, true_paths  # noqa: E402
from rig import exit_codes  # noqa: E402
from rig.cli import main as rig_main  # noqa: E402
from rig.staircase_points import staircase_steady_samples  # noqa: E402
from rig.log_file import LogWriter, read_log, write_log  # noqa: E402
from sim_backend.plant_config import load_plant_config  # noqa: E402

CONFIGS = ROOT / "configs"
SET_MEMBERSHIP_PLANT = CONFIGS / "plants" / "cerone2009.toml"
HAMMERSTEIN_PLANT = CONFIGS / "plants" / "pouliquen2013_backlash.toml"
STEADY = CONFIGS / "experiments" / "steady_staircase.toml"
PRBS = CONFIGS / "experiments" / "prbs.toml"
CYCLIC = CONFIGS / "experiments" / "hammerstein_cyclic.toml"
PRBS_SAMPLES = 1000
NA, NK, NB = 2, 1, 2
BACKLASH_KEYS = ("m_l", "c_l", "m_r", "c_r")
DIAGNOSE_SEED_OFFSET = 1000
DIAGNOSE_ENCODER_BITS = 12
DIAGNOSE_NOISE_RAD = 2.0e-4
BURST_SAMPLES = 50
PATTERNS = (("0 %", "random", 0.0), ("0.1 %", "random", 0.001), ("1 %", "random", 0.01), ("5 %", "random", 0.05),
            (f"1 % in bursts of {BURST_SAMPLES}", "burst", 0.01))
"""(row label, how the samples are lost, fraction of each record's samples)."""
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "RIG_BLAS_THREADS")


# --- losing samples ------------------------------------------------------------------------------------------

def lost_indices(size: int, kind: str, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Sorted sample numbers to mark LOST: ``round(fraction * size)`` (at least one) scattered at random, or
    as many in bursts of :data:`BURST_SAMPLES` (at least one burst), placed uniformly without overlap."""
    if fraction == 0.0:
        return np.empty(0, dtype=np.int64)
    count = max(1, round(fraction * size))
    if kind == "random":
        return np.sort(rng.choice(size, count, replace=False))
    bursts = max(1, round(count / BURST_SAMPLES))
    # k sorted distinct slots among size - k (L - 1); burst i starts at slot_i + i (L - 1): no two overlap
    slots = np.sort(rng.choice(size - bursts * (BURST_SAMPLES - 1), bursts, replace=False))
    starts = slots + np.arange(bursts) * (BURST_SAMPLES - 1)
    return (starts[:, None] + np.arange(BURST_SAMPLES)).ravel()


def mark_lost(source: Path, target: Path, lost: np.ndarray) -> None:
    """``source`` written to ``target`` with the samples ``lost`` flagged LOST, as a run writes them: time and
    command kept, angle nan, encoder count empty (0 in the record)."""
    record = read_log(source)
    flags = (np.zeros(len(record), dtype=np.uint8) if record.flags is None else record.flags.copy())
    flags[lost] |= np.uint8(SampleFlag.LOST)
    angle = record.angle_rad.copy()
    angle[lost] = np.nan
    counts = None if record.encoder_counts is None else record.encoder_counts.copy()
    if counts is not None:
        counts[lost] = 0
    write_log(target, dataclasses.replace(record, angle_rad=angle, encoder_counts=counts, flags=flags))


def rig(*arguments: str) -> tuple[int, str, str]:
    """``rig ARGUMENTS`` in this process: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = rig_main(list(arguments))
    return code, out.getvalue(), err.getvalue()


def error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.startswith("rig: error:")]
    return (lines[-1] if lines else stderr.strip().splitlines()[-1] if stderr.strip() else "?").removeprefix(
        "rig: error: ")


def simulate(plant: Path, excitation: Path, out: Path, seed: int) -> None:
    code, _, stderr = rig("simulate", str(plant), "--excitation", str(excitation), "--out", str(out), "--force",
                          "--seed", str(seed))
    if code != exit_codes.SUCCESS:
        sys.exit(f"rig simulate {plant.name} --excitation {excitation.name} failed ({code}): {stderr}")


# --- the three methods ---------------------------------------------------------------------------------------

def set_membership_truth() -> dict[str, float]:
    blocks = load_plant_config(SET_MEMBERSHIP_PLANT).plant.blocks
    linear = next(b for b in blocks if isinstance(b, LinearBlock))
    backlash = next(b for b in blocks if isinstance(b, OutputBacklash))
    return {"m_l": backlash.m_l, "c_l": backlash.c_l_rad, "m_r": backlash.m_r, "c_r": backlash.c_r_rad,
            **{f"a{i + 1}": a for i, a in enumerate(linear.a)},
            **{f"b{i}": linear.b[i] for i in range(NK, NB + 1)}}


def run_set_membership(steady: Path, dynamic: Path, truth: dict[str, float]) -> dict:
    noise_bound = read_log(dynamic).metadata.noise_bound_rad
    points = staircase_steady_samples(read_log(steady), steady, skip_unusable=True)
    case = {"early_points": int(np.count_nonzero(points.taken != points.ends)),
            "points_left": int(points.ends.size), "points": int(points.ends.size + len(points.unusable_ends))}
    code, stdout, stderr = rig("identify", "output-backlash", "--steady", str(steady), "--dynamic", str(dynamic),
                               "--noise-bound", repr(noise_bound), "--na", str(NA), "--nk", str(NK), "--nb", str(NB),
                               "--partition-samples", "0", "--json")
    if code == exit_codes.EMPTY_FEASIBLE_SET:
        return {**case, "status": "empty", "message": error_line(stderr).removeprefix("empty feasible set: ")}
    if code != exit_codes.SUCCESS:
        return {**case, "status": "refused", "message": error_line(stderr)}
    document = json.loads(stdout)
    bounds = {name: (float(v["lower"]), float(v["upper"])) for group in ("backlash", "linear")
              for name, v in document[group].items()}
    outside = {name: bounds[name] for name, value in truth.items() if not bounds[name][0] <= value <= bounds[name][1]}
    return {**case, "status": "ok", "bounds": bounds, "outside": outside,
            "equations_left_out": document["set_aside"]["equations_left_out"],
            "equations": document["set_aside"]["equations"]}


def border_rms(document: dict, truth: np.ndarray) -> float:
    """RMS on :data:`GRID` of both identified paths against the true ones (pouliquen2013_hammerstein.py)."""
    borders = document["borders"]
    estimate = np.concatenate([np.interp(GRID, borders[side]["u"], borders[side]["h"])
                               for side in ("ascending", "descending")])
    return float(np.sqrt(np.mean((estimate - truth) ** 2)))


def run_hammerstein(log: Path, truth: np.ndarray) -> dict:
    code, stdout, stderr = rig("identify", "hammerstein", str(log), "--json")
    if code != exit_codes.SUCCESS:
        return {"status": "refused", "message": error_line(stderr)}
    document = json.loads(stdout)
    aside = document["set_aside"]
    return {"status": "ok", "order": document["order"], "stable": document["stable"],
            "border_rms": border_rms(document, truth), "columns_left_out": aside["hankel_columns_left_out"],
            "columns": aside["hankel_columns"]}


def nominal_toml(record) -> str:
    """The record's nominal model (one linear block) as a plant TOML for ``rig diagnose --model``, with the
    record's encoder and noise (:data:`DIAGNOSE_ENCODER_BITS`, :data:`DIAGNOSE_NOISE_RAD`)."""
    (linear,) = record.nominal_model.blocks
    return (f'name = "nominal"\nsample_period_s = {record.sample_period_s!r}\n\n[encoder]\n'
            f'bits = {DIAGNOSE_ENCODER_BITS}\n\n[noise]\nkind = "uniform"\nbound_rad = {DIAGNOSE_NOISE_RAD!r}\n\n'
            f'[[blocks]]\ntype = "linear"\na = [{", ".join(map(repr, linear.a))}]\n'
            f'b = [{", ".join(map(repr, linear.b))}]\n')


def write_record_log(path: Path, record, lost: np.ndarray) -> None:
    """A rig log of a hidden-effect record with the samples ``lost`` LOST (angle nan)."""
    flags = np.zeros(record.command_rad.size, dtype=np.uint8)
    flags[lost] = np.uint8(SampleFlag.LOST)
    angle = record.angle_rad.copy()
    angle[lost] = np.nan
    metadata = ExperimentMetadata(sample_period_s=record.sample_period_s, source="hidden_effect_record",
                                  noise_bound_rad=record.noise_bound_rad)
    with LogWriter(path, metadata, flush_every=record.command_rad.size) as log:
        log.append_many(np.arange(record.command_rad.size) * record.sample_period_s, record.command_rad, angle,
                        flags=flags)


def run_diagnose(log: Path, model: Path, noise_bound: float, truth: dict[str, float]) -> dict:
    code, stdout, stderr = rig("diagnose", str(log), "--model", str(model), "--noise-bound", repr(noise_bound),
                               "--json")
    if code != exit_codes.SUCCESS:
        return {"status": "refused", "message": error_line(stderr)}
    document = json.loads(stdout)
    named = [entry["effect"] for entry in document["missing_effects"]]
    intervals = next((entry["parameter_intervals"] for entry in document["missing_effects"]
                      if entry["effect"] == "backlash"), {})
    outside = {key: tuple(intervals[key]) for key, value in truth.items()
               if key in intervals and not intervals[key][0] <= value <= intervals[key][1]}
    return {"status": "ok", "verdict": document["verdict"], "named": named, "right":
            document["verdict"] == "named" and named == ["backlash"], "judged": sum(k in intervals for k in truth),
            "outside": outside, "relative_widths": [(intervals[k][1] - intervals[k][0]) / abs(value)
                                                    for k, value in truth.items() if k in intervals]}


# --- the study -----------------------------------------------------------------------------------------------

def study(seeds: list[int], folder: Path) -> dict[str, list[dict]]:
    """Every (row, seed) of every method: a list per method of dicts with ``row``, ``seed``, ``lost``, ``size``
    and the method's outcome."""
    sm_truth = set_membership_truth()
    hammerstein_truth = np.concatenate(true_paths("backlash"))
    prbs = folder / "prbs.toml"
    shipped = PRBS.read_text()
    if "num_samples = 100\n" not in shipped:
        sys.exit(f"{PRBS}: no line 'num_samples = 100' to lengthen to {PRBS_SAMPLES} samples")
    prbs.write_text(shipped.replace("num_samples = 100\n", f"num_samples = {PRBS_SAMPLES}\n"))
    results: dict[str, list[dict]] = {"set membership": [], "hammerstein": [], "diagnose": []}
    for seed in seeds:
        clean = {"steady": folder / f"steady_{seed}.csv", "dynamic": folder / f"prbs_{seed}.csv",
                 "cyclic": folder / f"cyclic_{seed}.csv"}
        simulate(SET_MEMBERSHIP_PLANT, STEADY, clean["steady"], seed)
        simulate(SET_MEMBERSHIP_PLANT, prbs, clean["dynamic"], seed)
        simulate(HAMMERSTEIN_PLANT, CYCLIC, clean["cyclic"], seed)
        sizes = {name: len(read_log(path)) for name, path in clean.items()}
        record = hidden_effect_record(("backlash",), DIAGNOSE_SEED_OFFSET + seed, encoder_bits=DIAGNOSE_ENCODER_BITS,
                                      noise_amplitude_rad=DIAGNOSE_NOISE_RAD)
        sizes["diagnose"] = record.command_rad.size
        entry = effect("backlash")
        diagnose_truth = entry.report(next(b for b in record.true_model.blocks if isinstance(b, entry.block_class)))
        model = folder / f"nominal_{seed}.toml"
        model.write_text(nominal_toml(record))
        for row, (label, kind, fraction) in enumerate(PATTERNS):
            lost = {name: lost_indices(size, kind, fraction, np.random.default_rng([seed, row, k]))
                    for k, (name, size) in enumerate(sizes.items())}
            logs = {name: folder / f"{name}_{seed}_{row}.csv" for name in sizes}
            for name in clean:
                mark_lost(clean[name], logs[name], lost[name])
            write_record_log(logs["diagnose"], record, lost["diagnose"])
            common = {"row": label, "seed": seed}
            started = time.perf_counter()
            outcome = run_set_membership(logs["steady"], logs["dynamic"], sm_truth)
            results["set membership"].append({
                **common, **outcome, "lost": (lost["steady"].size, lost["dynamic"].size),
                "size": (sizes["steady"], sizes["dynamic"]), "seconds": time.perf_counter() - started})
            started = time.perf_counter()
            outcome = run_hammerstein(logs["cyclic"], hammerstein_truth)
            results["hammerstein"].append({**common, **outcome, "lost": lost["cyclic"].size, "size": sizes["cyclic"],
                                           "seconds": time.perf_counter() - started})
            started = time.perf_counter()
            outcome = run_diagnose(logs["diagnose"], model, record.noise_bound_rad, diagnose_truth)
            results["diagnose"].append({**common, **outcome, "lost": lost["diagnose"].size, "size": sizes["diagnose"],
                                        "truth": diagnose_truth, "seconds": time.perf_counter() - started})
            for name in sizes:
                logs[name].unlink()
        print(f"  seed {seed} done", file=sys.stderr, flush=True)
    return results


# --- the tables ----------------------------------------------------------------------------------------------

def _median(values: list[float], fmt: str) -> str:
    return format(float(np.median(values)), fmt) if values else "-"


def _span(values) -> str:
    """'41' or '10-12': the range of counts over the seeds."""
    values = sorted(set(values))
    return str(values[0]) if len(values) == 1 else f"{values[0]}-{values[-1]}"


def _baseline(results: list[dict], seed: int) -> dict | None:
    """The same seed's outcome with nothing lost (None if that was not a result)."""
    return next((r for r in results if r["seed"] == seed and r["row"] == PATTERNS[0][0] and r["status"] == "ok"),
                None)


def _width(bounds: tuple[float, float]) -> float:
    return bounds[1] - bounds[0]


def set_membership_table(results: list[dict]) -> list[str]:
    lines = ["| lost | LOST samples: steady / dynamic | refused | empty set | all 8 bounds hold the truth | "
             "steady points taken early / left out (all seeds) | equations left out (of 998), median | "
             "c_l, c_r width (mrad), median | width / width with no loss, largest: m_l, c_l, m_r, c_r | "
             "the same: a1, a2, b1, b2 | s per run |",
             "|---" * 11 + "|"]
    for label, _, _ in PATTERNS:
        cases = [r for r in results if r["row"] == label]
        ok = [r for r in cases if r["status"] == "ok"]
        ratios = [{k: _width(r["bounds"][k]) / _width(base["bounds"][k]) for k in r["bounds"]} for r in ok
                  if (base := _baseline(results, r["seed"])) is not None]
        backlash = [max(ratio[k] for k in BACKLASH_KEYS) for ratio in ratios]
        linear = [max(v for k, v in ratio.items() if k not in BACKLASH_KEYS) for ratio in ratios]
        lines.append(" | ".join((
            f"| {label}", f"{_span(r['lost'][0] for r in cases)} / {_span(r['lost'][1] for r in cases)}",
            f"{sum(r['status'] == 'refused' for r in cases)} of {len(cases)}",
            str(sum(r["status"] == "empty" for r in cases)),
            f"{sum(not r['outside'] for r in ok)} of {len(ok)}",
            f"{sum(r['early_points'] for r in cases)} / {sum(r['points'] - r['points_left'] for r in cases)}",
            _median([r["equations_left_out"] for r in ok], ".0f"),
            f"{_median([1e3 * _width(r['bounds']['c_l']) for r in ok], '.3f')}, "
            f"{_median([1e3 * _width(r['bounds']['c_r']) for r in ok], '.3f')}",
            f"{max(backlash):.3f}" if backlash else "-", f"{max(linear):.3f}" if linear else "-",
            f"{np.median([r['seconds'] for r in cases]):.2f} |")))
    return lines


def hammerstein_table(results: list[dict]) -> list[str]:
    lines = ["| lost | LOST samples (of 4100) | refused | order not 2 | Hankel columns left out (of 4071), median | "
             "border RMS, median (largest) | border RMS change from no loss, median (largest) | s per run |",
             "|---" * 8 + "|"]
    for label, _, _ in PATTERNS:
        cases = [r for r in results if r["row"] == label]
        ok = [r for r in cases if r["status"] == "ok"]
        changes = [r["border_rms"] - base["border_rms"] for r in ok
                   if (base := _baseline(results, r["seed"])) is not None]
        lines.append(" | ".join((
            f"| {label}", _span(r["lost"] for r in cases),
            f"{sum(r['status'] == 'refused' for r in cases)} of {len(cases)}",
            str(sum(r["order"] != 2 for r in ok)), _median([r["columns_left_out"] for r in ok], ".0f"),
            f"{_median([r['border_rms'] for r in ok], '.4f')} ({max(r['border_rms'] for r in ok):.4f})" if ok else "-",
            f"{_median(changes, '+.4f')} ({max(changes, key=abs):+.4f})" if changes else "-",
            f"{np.median([r['seconds'] for r in cases]):.2f} |")))
    return lines


def diagnose_table(results: list[dict]) -> list[str]:
    lines = ["| lost | LOST samples (of 3000) | refused | named backlash alone (right) | other verdicts: names | "
             "backlash c_l, c_r intervals holding the truth | their width (% of the true value), median | "
             "s per run |", "|---" * 8 + "|"]
    for label, _, _ in PATTERNS:
        cases = [r for r in results if r["row"] == label]
        ok = [r for r in cases if r["status"] == "ok"]
        others = [f"{r['verdict']}: {'+'.join(r['named']) or '-'}" for r in ok if not r["right"]]
        judged = sum(r["judged"] for r in ok)
        lines.append(f"| {label} | {_span(r['lost'] for r in cases)} | "
                     f"{sum(r['status'] == 'refused' for r in cases)} of {len(cases)} | "
                     f"{sum(r['right'] for r in ok)} of {len(ok)} | {', '.join(others) or '-'} | "
                     f"{judged - sum(len(r['outside']) for r in ok)} of {judged} | "
                     f"{_median([100 * w for r in ok for w in r['relative_widths']], '.1f')} | "
                     f"{np.median([r['seconds'] for r in cases]):.2f} |")
    return lines


def findings(results: dict[str, list[dict]]) -> list[str]:
    """One line per refusal and per wrong answer (and per Hammerstein border error more than twice the same
    record's with nothing lost): method, row, seed, what was left, what was expected, what came out."""
    truth = set_membership_truth()
    lines = []
    for r in results["set membership"]:
        where = (f"set membership, {r['row']}, seed {r['seed']} (LOST {r['lost'][0]} of {r['size'][0]} steady, "
                 f"{r['lost'][1]} of {r['size'][1]} dynamic samples; {r['points_left']} of {r['points']} steady "
                 "points with a usable settled tail)")
        if r["status"] == "refused":
            lines.append(f"- refused: {where}: {r['message']}")
        elif r["status"] == "empty":
            lines.append(f"- WRONG (empty feasible set, the truth is feasible): {where}: {r['message']}")
        elif r["outside"]:
            lines.append(f"- WRONG (truth outside the bounds): {where}: " + "; ".join(
                f"{k} = {truth[k]:.6g} outside [{lo:.6g}, {hi:.6g}]" for k, (lo, hi) in r["outside"].items()))
    for r in results["hammerstein"]:
        where = f"Hammerstein, {r['row']}, seed {r['seed']} (LOST {r['lost']} of {r['size']} samples)"
        if r["status"] == "refused":
            lines.append(f"- refused: {where}: {r['message']}")
            continue
        if r["order"] != 2:
            lines.append(f"- order {r['order']} (true 2): {where}: border RMS {r['border_rms']:.4f}")
        base = _baseline(results["hammerstein"], r["seed"])
        if base is not None and r["border_rms"] > 2 * base["border_rms"]:
            lines.append(f"- border RMS more than doubled: {where}: {base['border_rms']:.4f} with nothing lost, "
                         f"{r['border_rms']:.4f} with {r['columns_left_out']} of the {r['columns']} Hankel columns "
                         "left out")
    for r in results["diagnose"]:
        where = f"diagnose, {r['row']}, seed {r['seed']} (LOST {r['lost']} of {r['size']} samples)"
        if r["status"] == "refused":
            lines.append(f"- refused: {where}: {r['message']}")
            continue
        if not r["right"]:
            lines.append(f"- WRONG (expected verdict named: backlash): {where}: {r['verdict']}: "
                         f"{'+'.join(r['named']) or '-'}")
        for key, (lo, hi) in r["outside"].items():
            lines.append(f"- WRONG (truth outside the interval): {where}: backlash {key} = {r['truth'][key]:.6g} "
                         f"outside [{lo:.6g}, {hi:.6g}]")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds (records) per row (default 5)")
    parser.add_argument("--first-seed", type=int, default=1, help="first seed (default 1)")
    parser.add_argument("--quick", action="store_true", help="one seed: a smoke run of about 30 s")
    parser.add_argument("--keep", metavar="DIR", default=None,
                        help="write the simulated logs into DIR and keep them (default: a temporary directory)")
    args = parser.parse_args()
    seeds = list(range(args.first_seed, args.first_seed + (1 if args.quick else args.seeds)))

    started_utc = datetime.datetime.now(datetime.timezone.utc)
    load_before = os.getloadavg()
    threads = ", ".join(f"{name}={os.environ.get(name, 'unset')}" for name in THREAD_VARIABLES)
    print(f"command: {shlex.join([Path(sys.executable).name, *sys.argv])}")
    print(f"date (UTC): {started_utc.isoformat(timespec='seconds')}; machine: {platform.node()}, "
          f"{platform.platform()}, {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, numpy {np.__version__}; BLAS threads: {threads} (rig's analysis "
          f"commands limit the BLAS to RIG_BLAS_THREADS, default 1); load average "
          f"{' '.join(f'{v:.2f}' for v in load_before)}", flush=True)

    folder = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rig-lost-bench-"))
    folder.mkdir(parents=True, exist_ok=True)
    wall = time.perf_counter()
    try:
        results = study(seeds, folder)
    finally:
        if not args.keep:
            shutil.rmtree(folder, ignore_errors=True)
    wall = time.perf_counter() - wall

    print(f"\n{len(seeds)} seed(s) per row: {', '.join(map(str, seeds))} (rig simulate --seed S; the diagnosed record "
          f"hidden_effect_record(('backlash',), {DIAGNOSE_SEED_OFFSET} + S)); LOST samples drawn by "
          "default_rng([S, row, record])")
    print(f"\n(a) set membership, rig identify output-backlash (coupled, --partition-samples 0): cerone2009, "
          f"steady_staircase (10000 samples) + PRBS of {PRBS_SAMPLES} samples; truth m_l, c_l, m_r, c_r, a1, a2, "
          "b1, b2 of the plant config\n")
    print("\n".join(set_membership_table(results["set membership"])))
    print("\n(b) Hammerstein, rig identify hammerstein (defaults): pouliquen2013_backlash, hammerstein_cyclic "
          "(4100 samples, 10 dB SNR); border RMS on [-3, 3], both paths, against the true paths\n")
    print("\n".join(hammerstein_table(results["hammerstein"])))
    print("\n(c) model discrepancy, rig diagnose --model NOMINAL.toml: one hidden backlash, 3000 samples, 12-bit "
          "encoder; right = verdict named, backlash alone\n")
    print("\n".join(diagnose_table(results["diagnose"])))
    listed = findings(results)
    print("\nRefusals, wrong answers, Hammerstein border errors more than doubled" + (":" if listed else ": none"))
    if listed:
        print("\n".join(listed))
    print(f"\nwall time {wall:.0f} s; load average at the end "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}; finished "
          f"{datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')}")


if __name__ == "__main__":
    main()
