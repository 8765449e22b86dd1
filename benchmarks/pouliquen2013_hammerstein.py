"""Reproduce Section IV of Pouliquen et al. (CDC 2013): switch and backlash, Monte Carlo, speed vs SIPPY.

G(q) = q^-1 (0.1994 - 0.1804 q^-1)/(1 - 1.8858 q^-1 + 0.9048 q^-2); noise v = (1 + 0.5 q^-1)/(1 - 0.85 q^-1) e
with Gaussian e scaled to SNR = var(G H[u]) / var(v) = 10 dB; j = 4000 Hankel columns; 8 uniform nodes on
[-3, 3] (n_p = 7 segments); case 1 the switch, case 2 the backlash of the paper (arctan borders).

For each case and each variant (``separate``: Remark 5, the default; ``rank1``: eq. (14), the paper;
``refined``: the default followed by the output-error refinement) the script prints

* mean and standard deviation of the estimated poles against the true ones;
* the mean relative error of the frequency response, mean over runs and over 256 frequencies of
  |G_hat(e^jw) - G(e^jw)| / |G(e^jw)|;
* the RMS error on [-3, 3] of the average border (over runs) against the true path, both paths together,
  and the mean over runs of the per-run RMS error;
* the validation RMS error: noise-free output of a fresh cyclic experiment against the model's simulation;
* the median time of one identification.

It then identifies a plain linear model u -> y on the same data (SIPPY's MOESP, and our PI-MOESP on the
scalar input) to show what ignoring the backlash costs, and times SIPPY's MOESP on the lifted data (z, y - mu0)
against ours. Figures (pole scatter, Bode magnitude, borders) go to ``benchmarks/out/`` as PNG.

Run::

    nice -n 10 .venv/bin/python benchmarks/pouliquen2013_hammerstein.py --runs 100
"""

from __future__ import annotations

import argparse
import contextlib
import io
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.signal

from identify.border_lifting import PathNodes, lifted_input
from identify.cyclic_excitation import cyclic_random_excitation
from identify.hammerstein_subspace import (
    DEFAULT_FUTURE_HORIZON,
    DEFAULT_PAST_HORIZON,
    HammersteinModel,
    identify_hammerstein,
    pi_moesp_observability,
)
from identify.plant_blocks import LinearBlock, PlantModel, pouliquen2013_backlash, pouliquen2013_switch

G = LinearBlock(a=(-1.8858, 0.9048), b=(0.0, 0.1994, -0.1804), sample_period_s=1.0)
TRUE_POLES = np.sort_complex(G.poles)
NUMERATOR, DENOMINATOR = np.array(G.b), np.array((1.0, *G.a))
NODES = PathNodes.uniform(-3.0, 3.0, 8)
HOLD = 100
NUM_COLUMNS = 4000
SNR_DB = 10.0
OMEGA = np.logspace(-3, np.log10(np.pi), 256)
GRID = np.linspace(-3.0, 3.0, 601)
OUT = Path(__file__).resolve().parent / "out"
VARIANTS = ("separate", "rank1", "refined")


def true_paths(case: str) -> tuple[np.ndarray, np.ndarray]:
    """P_a, P_d on GRID: the borders, plus the inner segments a backlash takes on Table I cycles."""
    if case == "backlash":
        return (np.maximum(np.arctan(GRID - 1.0), np.arctan(-2.0)),
                np.minimum(np.arctan(GRID + 1.0), np.arctan(2.0)))
    switch = pouliquen2013_switch()
    return (np.array([switch.ascending(v) for v in GRID]), np.array([switch.descending(v) for v in GRID]))


def plant(case: str) -> PlantModel:
    return PlantModel(((pouliquen2013_switch() if case == "switch" else pouliquen2013_backlash()), G))


def noisy_experiment(case: str, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    num_samples = NUM_COLUMNS + DEFAULT_PAST_HORIZON + DEFAULT_FUTURE_HORIZON - 1
    u = cyclic_random_excitation(num_samples, -3.0, 3.0, HOLD, rng=rng)
    y0 = plant(case).simulate(u)
    v = scipy.signal.lfilter([1.0, 0.5], [1.0, -0.85], rng.standard_normal(u.size))
    v *= np.sqrt(np.var(y0) / 10 ** (SNR_DB / 10) / np.var(v))
    return u, y0 + v


@dataclass
class Tally:
    poles: list[np.ndarray] = field(default_factory=list)
    response: list[np.ndarray] = field(default_factory=list)
    borders: list[np.ndarray] = field(default_factory=list)
    validation: list[float] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    wrong_order: int = 0

    def add(self, model: HammersteinModel, seconds: float, u_val: np.ndarray, y_val: np.ndarray) -> None:
        self.seconds.append(seconds)
        if model.order != 2:
            self.wrong_order += 1
            return
        self.poles.append(np.sort_complex(model.poles))
        self.response.append(model.frequency_response(OMEGA))
        self.borders.append(np.concatenate((np.interp(GRID, model.ascending_border.nodes_u, model.ascending_border.values),
                                            np.interp(GRID, model.descending_border.nodes_u, model.descending_border.values))))
        self.validation.append(float(np.sqrt(np.mean((model.simulate(u_val) - y_val)[HOLD:] ** 2))))

    def row(self, truth_response: np.ndarray, truth_borders: np.ndarray) -> dict[str, float]:
        poles = np.array(self.poles)
        borders = np.array(self.borders)
        relative = np.abs(np.array(self.response) - truth_response) / np.abs(truth_response)
        return {
            "mean_pole_error": float(np.max(np.abs(poles.mean(axis=0) - TRUE_POLES))),
            "pole_std": float(max(poles.real.std(axis=0).max(), poles.imag.std(axis=0).max())),
            "freq_error": float(relative.mean()),
            "border_rms_avg": float(np.sqrt(np.mean((borders.mean(axis=0) - truth_borders) ** 2))),
            "border_rms_run": float(np.mean(np.sqrt(np.mean((borders - truth_borders) ** 2, axis=1)))),
            "validation_rms": float(np.mean(self.validation)),
            "ms": 1e3 * float(np.median(self.seconds)),
            "wrong_order": self.wrong_order,
        }


def linear_pi_moesp(u: np.ndarray, y: np.ndarray, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """A plain linear state-space model u -> y by PI-MOESP (eqs. (8)-(13) with z = u), B, D by least squares."""
    p = f = DEFAULT_FUTURE_HORIZON
    U, s, _ = pi_moesp_observability(u, y, p, f)
    gamma = U[:, :order] * np.sqrt(s[:order])
    C = gamma[0]
    A = np.linalg.lstsq(gamma[:-1], gamma[1:], rcond=None)[0]
    # B, D, offset by least squares on the output
    columns = []
    for i in range(order):
        numerator, denominator = scipy.signal.ss2tf(A, np.eye(order)[:, i : i + 1], C[None, :], np.zeros((1, 1)))
        columns.append(scipy.signal.lfilter(np.squeeze(numerator), denominator, u))
    design = np.column_stack(columns + [u, np.ones_like(u)])
    theta = np.linalg.lstsq(design, y, rcond=None)[0]
    numerator, denominator = scipy.signal.ss2tf(A, theta[:order, None], C[None, :], np.array([[theta[order]]]))
    return np.squeeze(numerator), denominator, theta[-1]


def sippy_moesp(u: np.ndarray, y: np.ndarray, order: int) -> tuple[object, float] | None:
    try:
        from sippy_unipi import system_identification
    except ImportError:
        return None
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = system_identification(y, u.T if u.ndim == 2 else u, "MOESP", SS_f=DEFAULT_FUTURE_HORIZON,
                                      SS_p=DEFAULT_PAST_HORIZON, SS_fixed_order=order)
    return model, time.perf_counter() - start


def figures(case: str, tallies: dict[str, Tally], truth_borders: np.ndarray, truth_response: np.ndarray) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    OUT.mkdir(parents=True, exist_ok=True)
    tally = tallies["separate"]
    poles = np.array(tally.poles)
    paths = []
    fig, ax = plt.subplots(figsize=(5, 4.5))
    ax.plot(poles.real.ravel(), poles.imag.ravel(), "*", ms=4, label="estimated poles")
    ax.plot(TRUE_POLES.real, TRUE_POLES.imag, "+", ms=14, mew=2, color="k", label="system poles")
    ax.set(xlabel="real", ylabel="imaginary", title=f"{case}: eigenvalues of the estimated A ({len(poles)} runs)")
    ax.legend()
    ax.grid(True)
    paths.append(OUT / f"pouliquen2013_{case}_poles.png")
    fig.savefig(paths[-1], dpi=120, bbox_inches="tight")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogx(OMEGA, 20 * np.log10(np.abs(truth_response)), "k", lw=2, label="system")
    ax.semilogx(OMEGA, 20 * np.log10(np.abs(np.mean(tally.response, axis=0))), "r--", label="average estimate")
    ax.set(xlabel="frequency (rad/sample)", ylabel="|G| (dB)", title=f"{case}: Bode magnitude")
    ax.legend()
    ax.grid(True, which="both")
    paths.append(OUT / f"pouliquen2013_{case}_bode.png")
    fig.savefig(paths[-1], dpi=120, bbox_inches="tight")
    plt.close(fig)

    borders = np.array(tally.borders)
    mean, std = borders.mean(axis=0), borders.std(axis=0)
    n = GRID.size
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for part, label, colour in ((slice(0, n), "ascending", "tab:blue"), (slice(n, 2 * n), "descending", "tab:red")):
        ax.plot(GRID, truth_borders[part], color="k", lw=1.5)
        ax.plot(GRID, mean[part], "--", color=colour, label=f"{label}: average estimate")
        ax.fill_between(GRID, mean[part] - std[part], mean[part] + std[part], color=colour, alpha=0.2)
    ax.plot([], [], color="k", label="true paths")
    ax.set(xlabel="u", ylabel="H[u]", title=f"{case}: H[.] and its average estimate (band: ±1 sd)")
    ax.legend()
    ax.grid(True)
    paths.append(OUT / f"pouliquen2013_{case}_borders.png")
    fig.savefig(paths[-1], dpi=120, bbox_inches="tight")
    plt.close(fig)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="Monte Carlo runs per case (the paper: 100)")
    parser.add_argument("--seed", type=int, default=2013, help="seed of the whole study")
    parser.add_argument("--sippy-runs", type=int, default=3, help="runs timed with SIPPY (slow) per case")
    parser.add_argument("--no-figures", action="store_true")
    args = parser.parse_args()

    _, truth_response = scipy.signal.freqz(NUMERATOR, DENOMINATOR, worN=OMEGA)
    print(f"Pouliquen et al. 2013, Section IV: {args.runs} runs per case, seed {args.seed}, SNR {SNR_DB:g} dB, "
          f"j = {NUM_COLUMNS}, p = f = {DEFAULT_FUTURE_HORIZON}, 8 nodes (n_p = 7) on [-3, 3]")
    print(f"true poles {TRUE_POLES[0]:.4f}, {TRUE_POLES[1]:.4f}\n")
    table = []
    linear_rows = []
    speed_rows = []
    for case in ("switch", "backlash"):
        truth_borders = np.concatenate(true_paths(case))
        tallies = {variant: Tally() for variant in VARIANTS}
        linear_errors: list[float] = []
        linear_poles: list[np.ndarray] = []
        sippy_linear: list[float] = []
        rng = np.random.default_rng([args.seed, 0 if case == "switch" else 1])
        for run in range(args.runs):
            u, y = noisy_experiment(case, rng)
            u_val = cyclic_random_excitation(HOLD + 4000, -3.0, 3.0, HOLD, rng=rng)
            y_val = plant(case).simulate(np.concatenate((np.full(400, -3.0), u_val)))[400:]  # settled at mu0
            for variant in VARIANTS:
                kwargs = {"split": "rank1"} if variant == "rank1" else {"refine": variant == "refined"}
                start = time.perf_counter()
                model = identify_hammerstein(u, y, NODES, hold_samples=HOLD, **kwargs)
                tallies[variant].add(model, time.perf_counter() - start, u_val, y_val)
            # a linear model that ignores the nonlinearity
            numerator, denominator, offset = linear_pi_moesp(u, y)
            linear_poles.append(np.sort_complex(np.roots(denominator)))
            y_lin = offset + scipy.signal.lfilter(numerator, denominator, u_val)
            linear_errors.append(float(np.sqrt(np.mean((y_lin - y_val)[HOLD:] ** 2))))
            if run < args.sippy_runs:
                result = sippy_moesp(u, y - y.mean(), 2)
                if result is not None:
                    sippy_model, _ = result
                    sippy_linear.append(float(np.max(np.abs(np.sort_complex(np.linalg.eigvals(sippy_model.A)) - TRUE_POLES))))
                z = lifted_input(u, NODES)
                result = sippy_moesp(z, y - y[:HOLD].mean(), 2)
                if result is not None:
                    speed_rows.append((case, result[1]))
        for variant in VARIANTS:
            table.append((case, variant, tallies[variant].row(truth_response, truth_borders)))
        linear_rows.append((case, np.array(linear_poles), float(np.mean(linear_errors)), sippy_linear,
                            tallies["separate"].row(truth_response, truth_borders)["validation_rms"]))
        if not args.no_figures:
            for path in figures(case, tallies, truth_borders, truth_response):
                print(f"figure: {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path}")

    print()
    print("| case | B and mu | mean pole error | pole sd | freq. resp. error | border RMS (average) | "
          "border RMS (per run) | validation RMS | wrong order | ms / identification |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for case, variant, row in table:
        print(f"| {case} | {variant} | {row['mean_pole_error']:.1e} | {row['pole_std']:.1e} | "
              f"{100 * row['freq_error']:.2f} % | {row['border_rms_avg']:.3f} | {row['border_rms_run']:.3f} | "
              f"{row['validation_rms']:.4f} | {row['wrong_order']} | {row['ms']:.1f} |")
    print("\nTargets: |mean pole error| <= 5e-3, pole sd <= 1e-2, border RMS <= 0.05 (average border).")

    print("\nA linear model that ignores the nonlinearity (order 2, u -> y, same data):")
    print(f"| case | linear: mean pole error | linear: validation RMS | SIPPY MOESP u -> y: pole error "
          f"(first {args.sippy_runs} runs) | Hammerstein: validation RMS |")
    print("|---|---|---|---|---|")
    for case, poles, error, sippy_errors, hammerstein_error in linear_rows:
        sippy_text = f"{np.mean(sippy_errors):.1e}" if sippy_errors else "n/a (SIPPY not installed)"
        print(f"| {case} | {np.max(np.abs(poles.mean(axis=0) - TRUE_POLES)):.1e} | {error:.4f} | {sippy_text} | "
              f"{hammerstein_error:.4f} |")

    print("\nSpeed on the lifted data (14 inputs, j = 4000, p = f = 15, order 2):")
    ours = [row["ms"] for case, variant, row in table if variant == "separate"]
    print("| method | ms per identification |")
    print("|---|---|")
    print(f"| ours (identify_hammerstein, whole method, median) | {np.median(ours):.1f} |")
    if speed_rows:
        print(f"| SIPPY MOESP on (z, y - mu0), linear part only (median of {len(speed_rows)}) | "
              f"{1e3 * np.median([s for _, s in speed_rows]):.1f} |")
    else:
        print("| SIPPY MOESP | n/a: sippy-unipi is not installed (pip install -e .[bench]) |")


if __name__ == "__main__":
    main()
