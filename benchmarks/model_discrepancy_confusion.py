"""Confusion matrix of the model-discrepancy workflow on hidden-effect records (single effects, then two
effects at once), and a run on the real EMPS record.

For every effect (and for no effect) ``--cases`` records are simulated with random realistic parameters and a
12-bit encoder (:mod:`identify.discrepancy_cases`); the workflow sees the data, the noise bound and either the
nominal linear model (``--start given``) or nothing (``--start fitted``: it fits its own linear model). The
row is the true effect, the column the first effect named ("none" if nothing, "ambig" when the verdict is
ambiguous: candidates within their uncertainty of each other, none chosen); the gap reduction is
1 - gap_final / gap_initial. Also counted: cases where more effects than the true one were named, and how
many fitted parameters of a rightly named effect have an interval that contains the true value, and the median
width of those intervals in per cent of the true value.

Rows of two effects at once (``--pairs``, ``a+b``): a case is correct when exactly the two are named (in either
order); the table gives the named sets.

On an independent generator (``--generator independent``): the records come from
``benchmarks/independent_plants/drive_train_generator.py``, written from the physics alone by someone who never
read ``identify/`` (a two-mass drive train behind a stiff position servo, sampled exactly, plus one effect, some
of which our catalogue does not hold: a sensor that wraps at +-pi, cogging; some it holds in another form: encoder
eccentricity, Stribeck friction, Bouc-Wen hysteresis in the coupling (the catalogue's shaft friction is Dahl's), a
sensor gain heated by the motor's losses (the catalogue's drifting gain settles with one time constant); and the
catalogue-like drifting gain, Coulomb friction, gravity and backlash). Each row draws ``--cases`` records whose effect the generator says is excited (a record
whose effect is not excited is skipped, counted, and replaced by the next seed, at most ``--max-draws`` per
case); the excitations rotate through ``--excitations``. The workflow gets the record, a noise bound of half a
count plus 4.5 standard deviations of the generator's Gaussian noise (:func:`independent_noise_bound`), the
sample period and, with ``--start given``, the generator's nominal model converted exactly into a
:class:`~identify.plant_blocks.LinearBlock` (:func:`nominal_linear_block`: the continuous two-mass train with
its position servo, discretised with a zero-order hold; every case checks it against the generator's own
nominal twin). Each case is scored as: the right name (:data:`ACCEPTED_NAMES`: the catalogue effects that are
the same physics or its quasi-static map; none for effects the catalogue has no equivalent of; from a fitted
start also ``resonance``, the generator's shaft mode, :func:`accepted_names`), left open with its look-alikes
(nothing named, the verdict ambiguous and an accepted name among the effects it lists: the answer asked of effects
the record cannot separate), honest (nothing named, the verdict ambiguous or unexplained otherwise; on the clean
records, explained), under the bound (nothing named, and the effect moves the angle by no more than the noise
bound the workflow was given: the model without it agrees with the truth within the stated measurement error, so
the record cannot show it), confident wrong (only wrong effects named with a verdict that is not ambiguous, or
explained when the effect moves the angle by more than the noise bound), hedged wrong (wrong effects named, then
ambiguous), right with a wrong one besides, and not excited or an
error. Where the generator's truth maps onto a named parameter (:func:`truth_in_our_terms`), the intervals are
checked against it.

Run:  nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --cases 20 --start given --jobs 2
      nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --cases 5 --start fitted --jobs 2
      nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py --emps-only
      OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/model_discrepancy_confusion.py \
          --generator independent --cases 20 --start given --jobs 2
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import numpy as np

from identify.discrepancy_cases import hidden_effect_record
from identify.drive_train import DriveTrain
from identify.effect_catalogue import EFFECT_NAMES, effect
from identify.model_discrepancy import DiagnoseOptions, diagnose_model
from identify.plant_blocks import LinearBlock, PlantModel

TRUE_EFFECTS = ("none", *EFFECT_NAMES)  # every effect of the catalogue
PAIRS = ("gravity+rate_limit", "load_friction+gravity", "backlash+gravity", "delay+torque_limit",
         "shaft_play+load_friction")
"""Default rows of two effects at once: the servo with an arm (weight and speed limit, friction and weight),
an output play behind a drive with an arm, a lag before a torque-limited drive, a gear's play with friction
on the load it drives."""
EMPS = next((parent / "shared" / "realdata" for parent in Path(__file__).resolve().parents
             if (parent / "shared" / "realdata").is_dir()),
            Path(__file__).resolve().parents[2] / "shared" / "realdata") / "emps" / "DATA_EMPS.mat"
"""``shared/realdata`` next to the checkout or next to any folder above it (a git worktree sits deeper)."""


def run_case(effects: tuple[str, ...], seed: int, start: str) -> dict:
    """One hidden-effect record diagnosed: the named effects, the verdict, the gap reduction, and per named
    true effect how many of its parameter intervals hold the truth (``missed``: the others, with the truth
    and the interval, in the case's line on stderr)."""
    record = hidden_effect_record(effects, seed)
    started = time.perf_counter()
    result = diagnose_model(record.command_rad, record.angle_rad, record.noise_bound_rad,
                            record.sample_period_s, record.nominal_model if start == "given" else None)
    covered, missed, widths = [0, 0], [], []
    for name in set(effects) & set(result.missing_effects):
        entry = effect(name)
        truth = entry.report(next(b for b in record.true_model.blocks if isinstance(b, entry.block_class)))
        for key, (low, high) in result.parameter_intervals.get(name, {}).items():
            inside = low <= truth[key] <= high
            if truth[key] != 0.0:
                widths.append((high - low) / abs(truth[key]))
            covered[0] += inside
            covered[1] += 1
            if not inside:
                missed.append(f"{name}.{key}: truth {truth[key]:.4g} outside [{low:.4g}, {high:.4g}]")
    return {"named": tuple(result.missing_effects), "verdict": result.verdict,
            "reduction": 1.0 - result.final.gap_rad / result.initial.gap_rad if result.initial.gap_rad > 0 else 0.0,
            "covered": covered, "missed": missed, "widths": widths, "seconds": time.perf_counter() - started}


def _json_line(case: dict) -> str:
    """One case as a line of JSON for the log (``--from-log`` reads it back); a numpy number in it is written as
    the plain number, so that no case's line, and no table after it, is lost to its type."""
    return json.dumps(case, default=lambda value: value.item() if isinstance(value, np.generic) else str(value))


def _run_rows(rows: tuple[tuple[str, ...], ...], cases: int, start: str, first_seed: int,
              jobs: int) -> dict[tuple[str, ...], list[dict]]:
    tasks = [(row, first_seed + case) for row in rows for case in range(cases)]
    out: dict[tuple[str, ...], list[dict]] = {row: [] for row in rows}
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        results = pool.map(run_case, [t[0] for t in tasks], [t[1] for t in tasks], [start] * len(tasks))
        for (row, seed), result in zip(tasks, results):  # one line per case as it is done, on stderr
            out[row].append(result)
            print(f"  {'+'.join(row) or 'none'} seed {seed}: {result['verdict']} {'+'.join(result['named']) or '-'} "
                  f"({result['seconds']:.0f} s) " + _json_line({"row": list(row), "seed": seed, **result}),
                  file=sys.stderr, flush=True)
    return out


def confusion(cases: int, start: str, effects: tuple[str, ...], first_seed: int, jobs: int) -> None:
    started = time.perf_counter()
    runs = _run_rows(tuple(() if row == "none" else (row,) for row in effects), cases, start, first_seed, jobs)
    print(f"\nstart model: {start}; {cases} cases per row (seeds {first_seed}..{first_seed + cases - 1}); "
          f"{time.perf_counter() - started:.0f} s in all with {jobs} process(es)")
    confusion_table(runs, effects)


def confusion_table(runs: dict[tuple[str, ...], list[dict]], effects: tuple[str, ...]) -> None:
    """The confusion matrix of single-effect rows (``effects``: names, "none" for the clean records)."""
    columns = (*TRUE_EFFECTS, "ambiguous", "other")
    short = {name: name[:5] for name in columns} | {"dead_zone": "deadz", "coulomb_friction": "fric", "offset": "offs",
                                                    "gain_error": "gain", "load_friction": "lfric", "gravity": "grav",
                                                    "rate_limit": "rate", "torque_limit": "torq",
                                                    "shaft_play": "play"}
    print("| true \\ named | " + " | ".join(short[c] for c in columns)
          + " | correct | more named | median gap reduction | truth in interval | median width | median s |")
    print("|---" * (len(columns) + 7) + "|")
    diagonal = total = inside = intervals = 0
    for row in effects:
        results = runs[() if row == "none" else (row,)]
        counts = {column: 0 for column in columns}
        for result in results:
            named = result["named"][0] if result["named"] else ("ambiguous" if result["verdict"] == "ambiguous" else "none")
            counts[named if named in counts else "other"] += 1
        extras = sum(len(r["named"]) > (0 if row == "none" else 1) for r in results)
        covered = [sum(r["covered"][0] for r in results), sum(r["covered"][1] for r in results)]
        reductions = [r["reduction"] for r in results] if row != "none" else []
        median = f"{100 * np.median(reductions):.1f} %" if reductions else "-"
        diagonal, total = diagonal + counts[row], total + len(results)
        inside, intervals = inside + covered[0], intervals + covered[1]
        print(f"| {row} | " + " | ".join(str(counts[c]) for c in columns)
              + f" | {100 * counts[row] / len(results):.0f} % | {extras} | {median} | "
              + (f"{covered[0]} of {covered[1]}" if covered[1] else "-")
              + f" | {_median_width(results)} | {np.median([r['seconds'] for r in results]):.1f} |")
    print(f"\ndiagonal {diagonal} of {total} ({100 * diagonal / total:.1f} %); truth in interval {inside} of "
          f"{intervals} ({100 * inside / max(intervals, 1):.1f} %)")


def pairs(cases: int, start: str, rows: tuple[tuple[str, ...], ...], first_seed: int, jobs: int) -> None:
    """Two hidden effects at once: correct when exactly the two are named."""
    started = time.perf_counter()
    runs = _run_rows(rows, cases, start, first_seed, jobs)
    print(f"\ntwo effects at once, start model: {start}; {cases} cases per row (seeds {first_seed}.."
          f"{first_seed + cases - 1}); {time.perf_counter() - started:.0f} s in all with {jobs} process(es)")
    pairs_table(runs, rows)


def pairs_table(runs: dict[tuple[str, ...], list[dict]], rows: tuple[tuple[str, ...], ...]) -> None:
    """The rows of two effects at once."""
    print("| true effects | both named, nothing else | named sets (count) | ambiguous | median gap reduction | "
          "truth in interval | median width | median s |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        results = runs[row]
        right = sum(set(r["named"]) == set(row) for r in results)
        sets: dict[str, int] = {}
        for r in results:
            label = "+".join(r["named"]) if r["named"] else ("ambiguous" if r["verdict"] == "ambiguous" else "none")
            sets[label] = sets.get(label, 0) + 1
        covered = [sum(r["covered"][0] for r in results), sum(r["covered"][1] for r in results)]
        print(f"| {' + '.join(row)} | {right} of {len(results)} ({100 * right / len(results):.0f} %) | "
              + ", ".join(f"{k} ({v})" for k, v in sorted(sets.items(), key=lambda kv: -kv[1]))
              + f" | {sum(r['verdict'] == 'ambiguous' for r in results)} | "
              + f"{100 * np.median([r['reduction'] for r in results]):.1f} % | "
              + (f"{covered[0]} of {covered[1]}" if covered[1] else "-")
              + f" | {_median_width(results)} | {np.median([r['seconds'] for r in results]):.1f} |")


def _median_width(results: list[dict]) -> str:
    """The median width of the intervals of the rightly named parameters, in per cent of the true value
    (cases logged before the widths were, none)."""
    widths = [w for r in results for w in r.get("widths", [])]
    return f"{100 * np.median(widths):.1f} %" if widths else "-"


def tables_from_log(path: Path) -> None:
    """The tables of the cases a run logged on stderr (one JSON object per line after the case's summary),
    e.g. of a run stopped before its end: rows with the cases they have."""
    runs: dict[tuple[str, ...], list[dict]] = {}
    independent_runs: dict[str, list[dict]] = {}
    for line in path.read_text().splitlines():
        if "{" in line:
            case = json.loads(line[line.index("{"):])
            if case.get("generator") == "independent":
                independent_runs.setdefault(case["effect"], []).append(case)
            else:
                runs.setdefault(tuple(case["row"]), []).append(case)
    if independent_runs:
        print(f"\nfrom {path.name}: {sum(len(v) for v in independent_runs.values())} cases on the independent generator")
        start = next(iter(independent_runs.values()))[0].get("start", "given")
        independent_table(independent_runs, tuple(e for e in INDEPENDENT_EFFECTS if e in independent_runs), start)
    if not runs:
        return
    print(f"\nfrom {path.name}: {sum(len(v) for v in runs.values())} cases")
    singles = tuple("+".join(row) or "none" for row in runs if len(row) < 2)
    if singles:
        confusion_table(runs, singles)
    doubles = tuple(row for row in runs if len(row) == 2)
    if doubles:
        pairs_table(runs, doubles)


def emps(decimate: int, noise_bound_m: float) -> None:
    """Reference position qg -> measured motor position qm of the EMPS closed loop (metres, not radians:
    the workflow is unit-agnostic). qm moves in steps of 5e-8 m; the default bound is 20 such steps."""
    from scipy.io import loadmat

    if not EMPS.is_file():
        print(f"\nEMPS: {EMPS} not found, skipped")
        return
    data = loadmat(EMPS)
    t = np.ravel(data["t"])[::decimate]
    reference = np.ravel(data["qg"])[::decimate]
    measured = np.ravel(data["qm"])[::decimate]
    period = float(np.median(np.diff(t)))
    started = time.perf_counter()
    result = diagnose_model(reference, measured, noise_bound_m, period, None, progress=None)
    print(f"\nEMPS DATA_EMPS.mat: qg -> qm, every {decimate}th sample ({reference.size} samples, T = {period:g} s), "
          f"noise bound {noise_bound_m:g} m, fitted linear start model of order {result.linear_fit.order}; "
          f"{time.perf_counter() - started:.0f} s")
    print(f"initial gap {result.initial.gap_rad:.4g} m, {100 * result.initial.falsified_fraction:.1f} % falsified, "
          f"{len(result.initial.windows)} windows")
    for number, step in enumerate(result.steps, 1):
        parameters = ", ".join(f"{k} = {v:.4g}" for k, v in step.parameters.items())
        print(f"step {number}: {step.effect}: gap {step.gap_before_rad:.4g} -> {step.gap_after_rad:.4g} "
              f"({parameters}); signature scores "
              + ", ".join(f"{k} {v:.2f}" for k, v in step.evidence["signature_scores"].items()))
    print(f"final gap {result.final.gap_rad:.4g} m, {100 * result.final.falsified_fraction:.1f} % falsified; "
          f"{result.unexplained}")


# -- on an independent generator ----------------------------------------------------------------------------------

ESTIMATION_FRACTION = DiagnoseOptions().estimation_fraction
"""The workflow's estimation share (the rest of a record is its validation segment)."""
GENERATOR = Path(__file__).resolve().parent / "independent_plants" / "drive_train_generator.py"
INDEPENDENT_EFFECTS = ("none", "eccentricity", "wrap", "gain_drift", "gain_heating", "cogging", "stribeck",
                       "hysteresis", "coulomb", "gravity", "backlash")
"""The generator's effects, in the order of its README (the catalogue-like ones last)."""
INDEPENDENT_EXCITATIONS = ("steps", "chirp", "multisine", "prbs")
"""The excitations the cases rotate through. The generator's ``ramp`` (forward, then back once at the middle) is
left out by default: its one reversal falls in the estimation segment (the first 60 %), so the workflow says
"not excited" for every ramp record (the validation segment has no reversal to judge on)."""
INDEPENDENT_DURATION_S = {"steps": 5.0, "chirp": 3.0, "multisine": 3.0, "prbs": 3.0, "ramp": 6.0}
"""Record lengths at 1 kHz, near the 3 000 samples of our own cases: steps are held 0.3-1.5 s, so their records
are longer for the last 40 % to hold a reversal; the multisine's lowest line (0.2 Hz) is then under one period."""
NOISE_STD_RAD = 1.0e-4
"""The generator's white Gaussian noise (standard deviation), added before quantisation; 0.065 counts at 12 bit."""
NOISE_BOUND_SIGMAS = 4.5
"""The noise is Gaussian, so unbounded: the bound takes 4.5 standard deviations, exceeded with probability
6.8e-6 per sample (0.02 samples in a 3 000-sample record; the workflow tolerates 1 % falsified)."""

ACCEPTED_NAMES: dict[str, frozenset[str]] = {
    "none": frozenset(),
    "eccentricity": frozenset({"encoder_error"}),  # the catalogue's once-per-revolution (and 2nd) encoder error
    "wrap": frozenset(),  # a single-turn reading: no catalogue equivalent
    # y = (1 + g(t)) theta, g settling with one time constant: the catalogue's drifting gain; and on an absolute
    # angle near c != 0, y - c = (theta - c) + g(t) c + g(t) (theta - c), a drifting offset plus a gain error:
    # the two catalogue effects of the measurement's static scale
    "gain_drift": frozenset({"gain_drift", "gain_error", "offset"}),
    # the gain of a sensor heated by the motor's losses, (1 + alpha T(t)) theta with C T' = s tau^2 - T / R: a
    # drifting gain whose course follows the work the drive does, not one time constant; the same names
    "gain_heating": frozenset({"gain_drift", "gain_error", "offset"}),
    "cogging": frozenset(),  # a load torque periodic in the angle, 6-36 per revolution: none
    # the catalogue's friction with breakaway (load_friction: Coulomb, static, viscous; coulomb_friction: its
    # quasi-static output form), and the output backlash that quasi-static Coulomb friction maps onto
    "stribeck": frozenset({"load_friction", "coulomb_friction", "backlash"}),
    # dry friction in parallel with the coupling's spring (Bouc-Wen): the catalogue's shaft friction (Dahl's)
    "hysteresis": frozenset({"shaft_friction"}),
    "coulomb": frozenset({"load_friction", "coulomb_friction", "backlash"}),
    # (the encoder error is gravity's look-alike: a record that cannot tell them apart is ambiguous, listing both)
    "gravity": frozenset({"gravity"}),
    # play in the shaft between the servoed motor and the load inertia: shaft_play; its quasi-static map, an
    # output backlash, and Coulomb friction without stiction through a compliance (the same play operator)
    "backlash": frozenset({"shaft_play", "backlash", "coulomb_friction"}),
}
"""Per generator effect, the catalogue names that count as naming it rightly."""

OUTCOMES = ("right", "left_open", "honest", "under_bound", "confident_wrong", "hedged_wrong", "right_and_wrong",
            "not_excited")


def generator_module():
    """The clean-room generator, imported from its file (it is a script next to this one, not a package)."""
    import importlib.util

    name = "drive_train_generator"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, GENERATOR)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def nominal_linear_block(nominal: dict) -> LinearBlock:
    """The generator's nominal model (``nominal.json``: its parameters and equations) as our linear block.

    State x = (phi, phi', theta, theta') with phi = theta_m / N the motor angle at the load side, input the
    motor-side command u, output the load angle theta. Kinematic servo: phi'' = wc^2 (u/N - phi) - 2 zeta wc
    phi' (the motor ignores the shaft); cascade: J_m' phi'' = K_v (K_p (u/N - phi) - phi') - tau_s with
    J_m' = N^2 J_m, K_v = 2 zeta wc (J_m' + J_l), K_p = wc / (2 zeta). Shaft tau_s = k (phi - theta) +
    c (phi' - theta'), load J_l theta'' = tau_s - b theta'. The command is held over each sample and sample k
    is the angle at t_k, so the zero-order-hold discretisation (the matrix exponential of [[A, B], [0, 0]] T)
    is exact, and y_k = C x_k is strictly proper (b0 = 0)."""
    from scipy.linalg import expm

    gear = float(nominal["gear_ratio"])
    inertia = float(nominal["load_inertia_kg_m2"])
    stiffness = float(nominal["shaft_stiffness_nm_per_rad"])
    damping = float(nominal["shaft_damping_nm_s_per_rad"])
    viscous = float(nominal["viscous_friction_nm_s_per_rad"])
    wc = 2.0 * math.pi * float(nominal["position_loop_bandwidth_hz"])
    zeta = float(nominal["position_loop_damping_ratio"])
    period = float(nominal["sample_period_s"])
    A = np.zeros((4, 4))
    B = np.zeros(4)
    A[0, 1] = A[2, 3] = 1.0
    A[3] = (stiffness / inertia, damping / inertia, -stiffness / inertia, -(damping + viscous) / inertia)
    if nominal["servo"] == "kinematic":
        A[1, :2] = (-wc * wc, -2.0 * zeta * wc)
        B[1] = wc * wc / gear
    elif nominal["servo"] == "cascade":
        motor = gear**2 * float(nominal["motor_inertia_kg_m2"])
        velocity_gain = 2.0 * zeta * wc * (motor + inertia)
        position_gain = wc / (2.0 * zeta)
        A[1] = (-(velocity_gain * position_gain + stiffness) / motor, -(velocity_gain + damping) / motor,
                stiffness / motor, damping / motor)
        B[1] = velocity_gain * position_gain / (gear * motor)
    else:
        raise ValueError(f"nominal servo {nominal['servo']!r}: expected 'kinematic' or 'cascade'")
    augmented = np.zeros((5, 5))
    augmented[:4, :4], augmented[:4, 4] = A, B
    discrete = expm(augmented * period)
    return LinearBlock.from_state_space(discrete[:4, :4], discrete[:4, 4], (0.0, 0.0, 1.0, 0.0), 0.0, period)


def nominal_drive_train(nominal: dict, bandwidth_factor: float = 1.0) -> DriveTrain:
    """The generator's nominal cascade servo as our drive train, with physical units (so that the drive's
    torque can exclude a weight, :mod:`identify.model_discrepancy.drive_torque`). The two are the same
    equations: P position and P velocity loops with K_v = 2 zeta omega_c (N^2 J_m + J_l) and K_p = omega_c /
    (2 zeta) on the motor's own angle, no feedforward, a spring-damper shaft, the load's viscous friction. The
    command is the load angle (the generator's motor command over N). ``bandwidth_factor`` scales the loop's
    bandwidth: a start model whose servo is off (its stiffness by the factor squared)."""
    if nominal["servo"] != "cascade":
        raise ValueError("--start train needs --servo cascade: the kinematic servo has no motor the load pushes back")
    return DriveTrain(sample_period_s=float(nominal["sample_period_s"]), gear_ratio=float(nominal["gear_ratio"]),
                      motor_inertia_kg_m2=float(nominal["motor_inertia_kg_m2"]),
                      load_inertia_kg_m2=float(nominal["load_inertia_kg_m2"]),
                      shaft_stiffness_nm_per_rad=float(nominal["shaft_stiffness_nm_per_rad"]),
                      shaft_damping_nm_s_per_rad=float(nominal["shaft_damping_nm_s_per_rad"]),
                      viscous_friction_nm_s_per_rad=float(nominal["viscous_friction_nm_s_per_rad"]),
                      position_loop_bandwidth_hz=bandwidth_factor * float(nominal["position_loop_bandwidth_hz"]),
                      position_loop_damping_ratio=float(nominal["position_loop_damping_ratio"]))


def independent_noise_bound(nominal: dict) -> float:
    """Half a count (the encoder rounds to the nearest count) plus :data:`NOISE_BOUND_SIGMAS` standard
    deviations of the Gaussian noise the generator adds before rounding."""
    return 0.5 * float(nominal["count_rad"]) + NOISE_BOUND_SIGMAS * float(nominal["noise_std_rad"])


def static_compliance_rad_per_nm(nominal: dict) -> float:
    """How far a steady torque at the load moves the generator's load angle (rad per N m): the shaft's 1 / k, and
    behind the cascade servo also its position loop's 1 / (K_v K_p) = 1 / (omega_c^2 (N^2 J_m + J_l)) (at rest the
    velocity loop's torque K_v K_p (u / N - phi) holds the shaft's; the kinematic servo holds the motor exactly)."""
    compliance = 1.0 / float(nominal["shaft_stiffness_nm_per_rad"])
    if nominal["servo"] == "cascade":
        wc = 2.0 * math.pi * float(nominal["position_loop_bandwidth_hz"])
        reflected = float(nominal["gear_ratio"]) ** 2 * float(nominal["motor_inertia_kg_m2"])
        compliance += 1.0 / (wc * wc * (reflected + float(nominal["load_inertia_kg_m2"])))
    return compliance


def shaft_mode(nominal: dict) -> dict[str, float]:
    """The generator's nominal plant's most lightly damped pole pair (its shaft mode: 30.8 Hz, damping ratio
    0.05 by default), from its own continuous-time matrices, as a resonance's ``frequency_hz`` and
    ``damping_ratio``."""
    a, _ = generator_module().linear_matrices(nominal)
    poles = [pole for pole in np.linalg.eigvals(a) if pole.imag > 0.0]
    pole = min(poles, key=lambda p: -p.real / abs(p))
    return {"frequency_hz": float(abs(pole) / (2.0 * math.pi)), "damping_ratio": float(-pole.real / abs(pole))}


def _train_of(model: PlantModel) -> DriveTrain | None:
    return next((b for b in model.blocks if isinstance(b, DriveTrain)), None)


def truth_in_our_terms(truth: dict, nominal: dict, name: str, model: PlantModel,
                       operating_point_rad: float, duration_s: float) -> dict[str, float]:
    """The generator's truth as the parameters our effect ``name`` reports, where the two describe the same
    thing; parameters without a counterpart are left out (not compared).

    A load torque tau sags the generator's load by tau times its static compliance
    (:func:`static_compliance_rad_per_nm`: the shaft's 1 / k, behind a cascade servo also the position loop's);
    in our train (the rigid drive train, or one with a shaft of stiffness k') the same torque per inertia
    X = tau / J leaves a static error X / omega_n^2 (+ X J / k'). So X is compared at the same static sag: X = (tau s) / (1 / omega_n^2 + J / k'),
    with s the generator's compliance and omega_n and J of the train in ``model``. Output backlash and Coulomb
    friction through a compliance report twists: the play's half-width b_h, or the sliding twist F_c s of
    quasi-static friction (breakaway F_s s); the viscous friction a load friction adds is zero (the
    nominal load's is the model's). The hanging angle is reported from the operating
    point the workflow moved to: theta_0 - y_0. A resonance (a right name from a fitted start only) is the
    nominal plant's own shaft mode (:func:`shaft_mode`). The coupling's hysteresis is the twist its friction
    holds, T_h / k. A drifting gain g_end (1 - exp(-t / tau)) / (1 - exp(-L / tau)) over a record of ``duration_s``
    L moves by dg = g_end / (1 - exp(-L / tau)) from a start of zero, and its zero, in the frame of the operating
    point y_0 the workflow moved to, by dg y_0. The effects without a catalogue equivalent are not compared."""
    p = truth["parameters"]
    effect_name = truth["effect"]
    if name == "resonance":
        return shaft_mode(nominal)
    compliance_of_generator = static_compliance_rad_per_nm(nominal)
    sliding = {"coulomb": p.get("coulomb_nm"), "stribeck": p.get("coulomb_nm")}.get(effect_name)
    breakaway = {"coulomb": p.get("coulomb_nm"), "stribeck": p.get("static_nm")}.get(effect_name)
    if name in ("load_friction", "gravity"):
        train = _train_of(model)
        if train is None:
            return {}
        compliance = 1.0 / train.natural_frequency_rad_per_s**2 + (
            0.0 if train.rigid else train.total_inertia_kg_m2 / train.shaft_stiffness_nm_per_rad)
        if name == "gravity" and effect_name == "gravity":
            return {"gravity_per_inertia_rad_per_s2": p["mgr_nm"] * compliance_of_generator / compliance,
                    "hanging_angle_rad": p["hanging_angle_rad"] - operating_point_rad}
        if name == "load_friction" and sliding is not None:
            # the effect reports the viscous friction it adds to the train, and the generator's Coulomb and
            # Stribeck frictions add none (the nominal load's viscous friction is the model's)
            return {"coulomb_per_inertia_rad_per_s2": sliding * compliance_of_generator / compliance,
                    "static_per_inertia_rad_per_s2": breakaway * compliance_of_generator / compliance,
                    "viscous_per_inertia_per_s": 0.0}
        return {}
    if name == "coulomb_friction" and sliding is not None:
        return {"breakaway_deflection_rad": breakaway * compliance_of_generator,
                "sliding_deflection_rad": sliding * compliance_of_generator}
    if name == "backlash" and sliding is not None:
        return {"c_l_rad": sliding * compliance_of_generator, "c_r_rad": sliding * compliance_of_generator}
    if name == "backlash" and effect_name == "backlash":
        return {"c_l_rad": p["half_width_rad"], "c_r_rad": p["half_width_rad"]}
    if name == "gain_drift" and effect_name == "gain_drift":
        tau = p["time_constant_s"]
        change = p["final_gain_error"] / -math.expm1(-duration_s / tau)
        return {"start_relative_error": 0.0, "relative_error_change": change, "time_constant_s": tau,
                "zero_change_rad": change * operating_point_rad}
    if name == "shaft_friction" and effect_name == "hysteresis":
        # the twist the friction holds against the spring, T_h / k; the presliding twists are not the same
        # parameter (Bouc-Wen's beta = gamma = 1/2 unloads at 1 / d_h, Dahl's at up to 2 / d_h)
        return {"friction_twist_rad": p["torque_nm"] / float(nominal["shaft_stiffness_nm_per_rad"])}
    if name == "shaft_play" and effect_name == "backlash":
        return {"play_rad": 2.0 * p["half_width_rad"]}
    if name == "coulomb_friction" and effect_name == "backlash":
        return {"breakaway_deflection_rad": p["half_width_rad"], "sliding_deflection_rad": p["half_width_rad"]}
    return {}


def _effect_in_validation(record: dict) -> bool:
    """Whether the effect shows in the validation segment (the last 40 %) by the generator's own test: the
    clean sensor angle more than half a count from the nominal twin's, or for a wrapping sensor a reading
    more than pi from the multi-turn angle there."""
    truth = record["truth"]
    start = int(round(ESTIMATION_FRACTION * record["angle_rad"].size))
    clean = record["clean_angle_rad"][start:]
    if truth["effect"] == "wrap":
        return bool(np.any(np.abs(record["angle_rad"][start:] - clean) > math.pi))
    return bool(np.max(np.abs(clean - record["nominal_state"][start:, 2])) > 0.5 * truth["count_rad"])


def _inside(key: str, value: float, low: float, high: float) -> bool:
    """``value`` in [low, high]; an angle also one or more turns away (a hanging angle is known modulo 2 pi)."""
    if key == "hanging_angle_rad":
        turns = math.ceil((low - value) / (2.0 * math.pi))
        return value + 2.0 * math.pi * turns <= high
    return low <= value <= high


def accepted_names(effect_name: str, start: str) -> frozenset[str]:
    """:data:`ACCEPTED_NAMES` of a row; from a fitted start also ``resonance``: the generator's nominal plant
    has a shaft mode (30.8 Hz, damping ratio 0.05) that a fitted start model (order 2 at most) cannot hold, so
    a resonance names what that start model is missing, in every row."""
    return ACCEPTED_NAMES[effect_name] | (frozenset({"resonance"}) if start == "fitted" else frozenset())


def _shows(effect_peak_rad: float, noise_bound_rad: float) -> bool:
    """An effect that moves the angle by more than the noise bound can show in the record; below it the model
    without the effect agrees with the record within the stated error."""
    return effect_peak_rad > noise_bound_rad


def independent_outcome(effect_name: str, named: tuple[str, ...], verdict: str, start: str = "given",
                        effect_peak_rad: float = math.inf, noise_bound_rad: float = 0.0,
                        left_open: tuple[str, ...] = ()) -> str:
    """The case's column (:data:`OUTCOMES`); ``effect_peak_rad`` is the most the effect moves the measured angle
    (the generator's ``effect_size.max_abs_rad``), ``noise_bound_rad`` the bound the workflow was given,
    ``left_open`` the effects an ambiguous verdict lists (``ambiguous_between``).

    A name is scored whatever the effect's size. Where nothing is named: an effect that moves the angle by no
    more than the noise bound is ``under_bound`` (the model without it agrees with the record within the stated
    error, so no answer can be faulted); an ambiguous verdict that lists an accepted name among the effects it
    cannot separate is ``left_open`` (what the workflow is asked to say of look-alikes); anything else is
    ``honest``, but ``explained`` over an effect above the bound is ``confident_wrong``."""
    if verdict == "not_excited":
        return "not_excited"
    accepted = accepted_names(effect_name, start)
    if effect_name == "none":
        if verdict == "explained" or (start == "fitted" and not named):  # a fitted start lacks the shaft mode
            return "honest"
        if named and all(name in accepted for name in named):
            return "right"
        return "confident_wrong" if named and verdict != "ambiguous" else "hedged_wrong"
    if named:
        right = [name in accepted for name in named]
        if all(right):
            return "right"
        if any(right):
            return "right_and_wrong"
        return "hedged_wrong" if verdict == "ambiguous" else "confident_wrong"
    if not _shows(effect_peak_rad, noise_bound_rad):
        return "under_bound"
    if verdict == "explained":
        return "confident_wrong"
    if verdict == "ambiguous" and accepted & set(left_open):
        return "left_open"
    return "honest"


def run_independent_case(effect_name: str, case: int, cases: int, first_seed: int, start: str,
                         excitations: tuple[str, ...], durations: dict[str, float], max_draws: int,
                         bits: int, noise_std_rad: float, servo: str = "kinematic",
                         torque_noise_nm: float | None = None, bandwidth_factor: float = 1.0) -> dict:
    """One case of a row: the first excited record of seeds first_seed + case + j cases (j = 0, 1, ...; the
    excitation rotates with case + j), diagnosed and scored; with ``torque_noise_nm`` the workflow also gets the
    generator's drive torque (its torque actual value, with that noise), else the angle alone."""
    generator = generator_module()
    skipped: list[str] = []
    for draw in range(max_draws):
        seed = first_seed + case + draw * cases
        excitation = excitations[(case + draw) % len(excitations)]
        record = generator.generate(effect_name, seed, excitation=excitation, duration_s=durations[excitation],
                                    bits=bits, noise_rad=noise_std_rad, nominal={"servo": servo},
                                    torque_noise_nm=torque_noise_nm or 0.0)
        if record["truth"]["excited"] or effect_name == "none":
            break
        skipped.append(f"{seed}/{excitation}")
    else:
        return {"effect": effect_name, "case": case, "seed": None, "excitation": None, "skipped": skipped,
                "outcome": "skipped", "named": [], "verdict": "-", "covered": [0, 0], "missed": [], "seconds": 0.0}
    truth, nominal = record["truth"], record["nominal"]
    delta = independent_noise_bound(nominal)
    command, angle = record["command_rad"], record["angle_rad"]
    twin = record["nominal_state"][:, 2]
    if start == "train":  # our drive train integrates the same equations: agreement to a fraction of the bound
        block = nominal_drive_train(nominal)
        command = command / float(nominal["gear_ratio"])
        conversion_error, tolerance = float(np.max(np.abs(block.apply(command - command[0]) + command[0] - twin))), 0.05 * delta
        block = nominal_drive_train(nominal, bandwidth_factor)
    else:
        block = nominal_linear_block(nominal)
        conversion_error, tolerance = float(np.max(np.abs(block.apply(command - command[0]) + command[0] - twin))), 1e-8
    if conversion_error > tolerance:
        raise RuntimeError(f"{effect_name} seed {seed}: our {type(block).__name__} differs from the generator's nominal "
                           f"twin by {conversion_error:.3g} rad")
    started = time.perf_counter()
    peak_rad = truth["effect_size"].get("max_abs_rad", math.inf)
    if effect_name == "wrap":  # the generator sizes an effect on the clean angle, which a wrap leaves alone
        peak_rad = float(np.max(np.abs(record["angle_rad"] - record["clean_angle_rad"])))
    base = {"effect": effect_name, "case": case, "seed": seed, "excitation": excitation, "skipped": skipped,
            "effect_size_counts": truth["effect_size"].get("max_abs_counts"),
            "effect_peak_rad": peak_rad,
            "in_validation": _effect_in_validation(record), "noise_bound_rad": delta,
            "conversion_error_rad": conversion_error}
    try:
        result = diagnose_model(command, angle, delta, float(nominal["sample_period_s"]),
                                None if start == "fitted" else PlantModel((block,)),
                                drive_torque=None if torque_noise_nm is None else record["torque_nm"],
                                drive_torque_nm_per_unit=None if torque_noise_nm is None else 1.0)
    except Exception as err:  # a crash is a result of the benchmark, not the end of the run
        return {**base, "outcome": "not_excited", "named": [], "verdict": f"error: {type(err).__name__}: {err}",
                "covered": [0, 0], "missed": [], "seconds": time.perf_counter() - started}
    named = tuple(result.missing_effects)
    covered, missed = [0, 0], []
    for name in set(named) & accepted_names(effect_name, start):
        ours = truth_in_our_terms(truth, nominal, name, result.final_model, result.operating_point_rad,
                                  command.size * float(nominal["sample_period_s"]))
        for key, (low, high) in result.parameter_intervals.get(name, {}).items():
            if key not in ours:
                continue
            inside = _inside(key, ours[key], low, high)
            covered[0] += inside
            covered[1] += 1
            if not inside:
                missed.append(f"{name}.{key}: truth {ours[key]:.4g} outside [{low:.4g}, {high:.4g}]")
    return {**base, "outcome": independent_outcome(effect_name, named, result.verdict, start,
                                                   base["effect_peak_rad"], delta, result.ambiguous_between),
            "named": list(named),
            "ambiguous_between": list(result.ambiguous_between), "verdict": result.verdict,
            "reason": result.verdict_reason[:400], "restarted": result.restart_window_samples is not None,
            "torque_check": None if result.load_torque_check is None else result.load_torque_check.outcome,
            "reduction": 1.0 - result.final.gap_rad / result.initial.gap_rad if result.initial.gap_rad > 0 else 0.0,
            "covered": covered, "missed": missed, "seconds": time.perf_counter() - started}


def independent(cases: int, start: str, effects: tuple[str, ...], first_seed: int, jobs: int,
                excitations: tuple[str, ...], durations: dict[str, float], max_draws: int, bits: int,
                noise_std_rad: float, servo: str = "kinematic", torque_noise_nm: float | None = None,
                bandwidth_factor: float = 1.0) -> None:
    """Every row of ``effects`` on the independent generator; a line per case on stderr, then the table."""
    started = time.perf_counter()
    tasks = [(name, case) for name in effects for case in range(cases)]
    runs: dict[str, list[dict]] = {name: [] for name in effects}
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        futures = [pool.submit(run_independent_case, name, case, cases, first_seed, start, excitations, durations,
                               max_draws, bits, noise_std_rad, servo, torque_noise_nm, bandwidth_factor)
                   for name, case in tasks]
        for future in as_completed(futures):  # a line per case as soon as it is done
            result = future.result()
            runs[result["effect"]].append(result)
            print(f"  {result['effect']} seed {result['seed']} {result['excitation']}: {result['outcome']}: "
                  f"{result['verdict']} {'+'.join(result['named']) or '-'} ({result['seconds']:.0f} s) "
                  + _json_line({"generator": "independent", "start": start, **result}),
                  file=sys.stderr, flush=True)
    print(f"\non the independent generator, start model: {start}; {cases} cases per row (seeds from {first_seed}, "
          f"excitations {', '.join(excitations)}, {bits}-bit encoder, noise std {noise_std_rad:g} rad, {servo} "
          f"servo; " + (f"start model's loop bandwidth x {bandwidth_factor:g}; " if bandwidth_factor != 1.0 else "")
          + ("the angle alone" if torque_noise_nm is None else
                        f"with the drive's torque, noise std {torque_noise_nm:g} N m") + "); "
          f"{time.perf_counter() - started:.0f} s in all with {jobs} process(es)")
    independent_table(runs, effects, start)


def _above_bound(case: dict) -> bool:
    """Whether the case's effect moves the angle by more than the noise bound the workflow was given (a case
    logged without the two: yes)."""
    return _shows(case.get("effect_peak_rad", math.inf), case.get("noise_bound_rad", 0.0))


def independent_table(runs: dict[str, list[dict]], effects: tuple[str, ...], start: str = "given") -> None:
    """One row per generator effect: the outcome counts, what was named, and the intervals of right names."""
    print("| effect | accepted names | right | left open with its look-alikes | honest | under the bound, nothing named | "
          "confident wrong | hedged wrong | "
          "right + wrong | not excited / error | skipped (not excited) | named (count) | truth in interval | median s |")
    print("|---" * 14 + "|")
    for name in effects:
        runs[name] = sorted(runs.get(name, []), key=lambda r: r["case"])
        results = [r for r in runs[name] if r["outcome"] != "skipped"]
        counts = {outcome: sum(r["outcome"] == outcome for r in results) for outcome in OUTCOMES}
        skipped = sum(len(r["skipped"]) for r in runs.get(name, []))
        labels: dict[str, int] = {}
        for r in results:
            if r["named"]:
                label = "+".join(r["named"]) + (" (then ambiguous)" if r["verdict"] == "ambiguous" else "")
                label += " (restarted)" if r.get("restarted") else ""
            else:
                label = r["verdict"].split(":")[0]
            labels[label] = labels.get(label, 0) + 1
        covered = [sum(r["covered"][0] for r in results), sum(r["covered"][1] for r in results)]
        seconds = [r["seconds"] for r in results]
        print(f"| {name} | {', '.join(sorted(accepted_names(name, start))) or '-'} | "
              + " | ".join(str(counts[o]) for o in OUTCOMES)
              + f" | {skipped} | " + ", ".join(f"{k} {v}" for k, v in sorted(labels.items(), key=lambda kv: -kv[1]))
              + " | " + (f"{covered[0]} of {covered[1]}" if covered[1] else "-")
              + f" | {np.median(seconds) if seconds else 0.0:.1f} |")
    print("\nrows with an accepted name, on the records whose effect moves the angle by more than the noise bound:")
    for name in effects:
        results = [r for r in runs[name] if r["outcome"] != "skipped"]
        above = [r for r in results if _above_bound(r)]
        if name == "none" or not accepted_names(name, start) or not above:
            continue
        right = sum(r["outcome"] == "right" for r in above)
        left_open = sum(r["outcome"] == "left_open" for r in above)
        under = [r for r in results if not _above_bound(r)]
        print(f"  {name}: named right {right} of {len(above)} ({100 * right / len(above):.0f} %); named right or "
              f"left open with its look-alikes {right + left_open} ({100 * (right + left_open) / len(above):.0f} %)"
              + (f"; under the bound: named right {sum(r['outcome'] == 'right' for r in under)} of {len(under)}"
                 if under else ""))
    checked = {name: [r["torque_check"] for r in runs.get(name, []) if r.get("torque_check")] for name in effects}
    if any(checked.values()):
        print("\nthe drive's torque check, where the angle left gravity open (outcome: cases):")
        for name, outcomes in checked.items():
            if outcomes:
                print(f"  {name}: " + ", ".join(f"{o} {outcomes.count(o)}" for o in sorted(set(outcomes))))
    results = [r for name in effects for r in runs.get(name, []) if r["outcome"] != "skipped"]
    print("\nconfident wrong answers, by what was said and the excitations it was said on:")
    for name in effects:
        said: dict[str, list[str]] = {}
        for r in runs.get(name, []):
            if r["outcome"] == "confident_wrong":
                said.setdefault("+".join(r["named"]) or r["verdict"], []).append(r["excitation"])
        if said:
            print(f"  {name}: " + "; ".join(
                f"-> {label} {len(exc)} ({', '.join(f'{e} {exc.count(e)}' for e in sorted(set(exc)))})"
                for label, exc in sorted(said.items(), key=lambda kv: -len(kv[1]))))
    for name in effects:
        wrong = [r for r in runs.get(name, []) if r["outcome"] == "confident_wrong" and name != "none"]
        early = [r for r in wrong if not r.get("in_validation", True)]
        if early:
            print(f"{name}: {len(early)} of {len(wrong)} confident wrong answers on records whose effect shows only in "
                  f"the estimation segment (the first {100 * ESTIMATION_FRACTION:.0f} %): "
                  + ", ".join(f"{r['verdict']} {'+'.join(r['named'])}".strip() for r in early))
    print(f"\n{len(results)} cases: " + ", ".join(f"{o.replace('_', ' ')} {sum(r['outcome'] == o for r in results)}"
                                              for o in OUTCOMES))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=20, help="random cases per true effect (default 20)")
    parser.add_argument("--start", choices=("given", "fitted", "train"), default="given",
                        help="given: the nominal model as a linear block (default); fitted: none (the workflow fits "
                             "one); train: independent generator, cascade servo: the nominal as our drive train, "
                             "with physical units")
    parser.add_argument("--start-bandwidth-factor", type=float, default=1.0, metavar="F",
                        help="--start train: the start model's position-loop bandwidth times F (a servo gain off)")
    parser.add_argument("--effects", default=None,
                        help="rows, comma-separated (default: all; with --start fitted all but gain_error, which a "
                             "fitted linear start model absorbs: no method can name it there)")
    parser.add_argument("--pairs", default=",".join(PAIRS),
                        help="rows of two effects, a+b comma-separated (default: %(default)s; '' for none)")
    parser.add_argument("--jobs", type=int, default=1, help="processes (default 1)")
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--emps-only", action="store_true")
    parser.add_argument("--no-emps", action="store_true")
    parser.add_argument("--from-log", type=Path, metavar="FILE",
                        help="print the tables of the cases logged (stderr) by an earlier run, and nothing else")
    parser.add_argument("--generator", choices=("ours", "independent"), default="ours",
                        help="ours: identify.discrepancy_cases (default); independent: the clean-room generator in "
                             "benchmarks/independent_plants (rows: its effects; no pairs, no EMPS)")
    parser.add_argument("--excitations", default=",".join(INDEPENDENT_EXCITATIONS),
                        help="independent generator: excitations the cases rotate through (default %(default)s)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="independent generator: record length for every excitation (default: "
                             + ", ".join(f"{k} {v:g} s" for k, v in INDEPENDENT_DURATION_S.items()) + ")")
    parser.add_argument("--max-draws", type=int, default=40,
                        help="independent generator: seeds tried per case for a record whose effect is excited")
    parser.add_argument("--bits", type=int, default=12, help="independent generator: encoder bits (default 12)")
    parser.add_argument("--noise-std", type=float, default=NOISE_STD_RAD, metavar="RAD",
                        help="independent generator: Gaussian noise std before quantisation (default %(default)g)")
    parser.add_argument("--servo", choices=("kinematic", "cascade"), default="kinematic",
                        help="independent generator: kinematic (the motor follows the command whatever the load does, "
                             "default) or cascade (position and velocity loops on a motor the shaft pushes back)")
    parser.add_argument("--drive-torque", type=float, default=None, metavar="NOISE_NM",
                        help="independent generator: give the workflow the drive's torque too (the generator's torque "
                             "actual value, per mille of 2 N m, with this Gaussian noise std in N m); default: the "
                             "angle alone")
    parser.add_argument("--emps-decimate", type=int, default=5)
    parser.add_argument("--emps-noise-bound", type=float, default=1e-6, metavar="M")
    args = parser.parse_args()
    if args.from_log is not None:
        tables_from_log(args.from_log)
        return
    if args.generator == "independent":
        durations = {k: (v if args.duration is None else args.duration) for k, v in INDEPENDENT_DURATION_S.items()}
        effects = INDEPENDENT_EFFECTS if args.effects is None else tuple(e for e in args.effects.split(",") if e)
        independent(args.cases, args.start, effects, args.first_seed, args.jobs,
                    tuple(e for e in args.excitations.split(",") if e), durations, args.max_draws, args.bits,
                    args.noise_std, args.servo, args.drive_torque, args.start_bandwidth_factor)
        return
    if args.effects is not None:
        effects = tuple(e for e in args.effects.split(",") if e)
    else:
        effects = tuple(e for e in TRUE_EFFECTS if args.start == "given" or e != "gain_error")
    if not args.emps_only:
        if effects:
            confusion(args.cases, args.start, effects, args.first_seed, args.jobs)
        rows = tuple(tuple(row.split("+")) for row in args.pairs.split(",") if row)
        if rows:
            pairs(args.cases, args.start, rows, args.first_seed, args.jobs)
    if not args.no_emps:
        emps(args.emps_decimate, args.emps_noise_bound)


if __name__ == "__main__":
    main()
