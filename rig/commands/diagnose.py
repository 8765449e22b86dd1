"""``rig diagnose DATA``: find where a model and a measurement disagree, name the missing physical effect, add
it with fitted parameters and show the gap shrink (:mod:`identify.model_discrepancy`)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from rig import exit_codes

DESCRIPTION = """\
Simulate the model on the measured command (free run), mark the samples where the residual exceeds the noise
bound, score the signatures of backlash, dead zone, saturation, delay, Coulomb friction, resonance,
offset/drift and gain error in the residual, add the effect that lowers the validated gap (RMS free-run error on the last
40 % of the record, which no fit sees) most beyond a complexity penalty, and repeat until the model is
consistent with the noise bound or no effect helps.

DATA is a rig log, a plain CSV with columns t, u, y (seconds, radians), an ASAM MDF4 (.mf4/.mdf) or
MATLAB (.mat) file (one written by `rig export`, or with channels t, u, y), or per-sample JSON records (an
object with an entries[] list, as the K-Scale sysid logger writes); --columns, --units and --valid read
other tools' files. One-sample read failures are replaced and counted, irregular sampling is resampled with a
note, and a record that starts at rest is run from rest at its first command. Without --model the start
model is the best linear model of order 1 or 2 (chosen by validation error). The noise bound must cover the
encoder's half count. With the drive's torque in the file (--columns ...,tau=NAME: a CiA 402 torque actual
value or a motor current, any unit), a weight on the load that the angle alone cannot tell from a sensor error
is checked in the torque the drive gives. A rig log also gives the torque's scale (its summary's
drive_torque_nm_per_unit, from the drive's rated torque 0x6076; --torque-scale gives it for another tool's
file); with it and a --model holding a drive train, a torque too small for the weight the sag would need
excludes the weight.

Example (a K-Scale STS3215 record, 4096 counts/rev: noise bound of a few counts):
  rig diagnose sysid.json --columns t=timestamp,u=goal_position,y=position --valid torque_enable \
      --noise-bound 0.005"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "diagnose",
        help="name the physical effect a model is missing, add it and show the gap shrink",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("data", metavar="DATA", nargs="+",
                        help="a rig log, a CSV with columns t,u,y, or .mf4/.mdf/.mat; several are diagnosed independently")
    parser.add_argument("--model", metavar="PLANT.toml|PLANT.fmu", default=None,
                        help="the user's model: a plant config, or an FMU (FMI 2.0/3.0, co-simulation or model "
                             "exchange; needs fmpy: pip install 'gearbox-rig[fmu]'); default: fit a linear model")
    parser.add_argument("--fmu-input", metavar="NAME", default=None,
                        help="the FMU's input that takes the commanded angle in rad (needed when it has several)")
    parser.add_argument("--fmu-parameter", metavar="NAME=VALUE", action="append", default=[],
                        help="with --model PLANT.fmu: set a parameter of the FMU before it starts (repeat for "
                             "several; `rig inspect PLANT.fmu` lists them with their ranges)")
    parser.add_argument("--fmu-output", metavar="NAME", default=None,
                        help="the FMU's output that gives the load angle in rad (needed when it has several)")
    parser.add_argument("--noise-bound", type=float, required=True, metavar="RAD",
                        help="bound on the measurement error |e_t| in rad (include the encoder's half count)")
    parser.add_argument("--torque-scale", type=float, default=None, metavar="NM_PER_UNIT",
                        help="N m at the motor per unit of the file's torque column (default: a rig log's summary "
                             "gives it; another tool's file none): with a --model holding the drive train, a torque "
                             "too small for the weight the sag needs excludes the weight")
    parser.add_argument("--report", metavar="DIR", default=None,
                        help="write figures and an HTML page to DIR (with several files: DIR/<file name>/)")
    parser.add_argument("--force", action="store_true",
                        help="write the --report into a directory that holds other files (not an earlier report)")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="diagnose several files in N processes (0: one per core; default 1)")
    parser.add_argument("--scheduler", metavar="ADDRESS", default=None,
                        help="run the files on the Dask cluster at ADDRESS instead (needs dask[distributed])")
    from rig.record_import import add_import_arguments

    add_import_arguments(parser)
    parser.add_argument("--json", action="store_true",
                        help='print the result as one JSON object; with several files '
                             '{"kind": "batch", "version": 1, "results": [{"file", "diagnosis" | "error"}]}')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from functools import partial

    import sys

    from rig.batch import batch_document, map_files

    from rig.record_import import options_from_arguments

    if args.torque_scale is not None and not (math.isfinite(args.torque_scale) and args.torque_scale > 0):
        raise ValueError(f"--torque-scale: expected the N m at the motor per unit of the torque column, a number "
                         f"> 0, got {args.torque_scale!r}")
    if args.report is not None:  # before the work: a diagnosis can take minutes
        from rig.output_paths import check_report_dir

        check_report_dir(args.report, "--report", inputs=args.data, force=args.force)
        _refuse_shared_report_names(args.data)
        if len(args.data) > 1:  # the reports go into subdirectories: the top one is the report of the batch
            from rig.output_paths import mark_report_dir

            Path(args.report).mkdir(parents=True, exist_ok=True)
            mark_report_dir(args.report)
    fmu = _fmu_options(args)
    options = {"model": args.model, "fmu": fmu, "noise_bound": args.noise_bound, "torque_scale": args.torque_scale,
               "report": args.report,
               "report_per_file": len(args.data) > 1, "import": options_from_arguments(args),
               "progress": not args.json and sys.stderr.isatty() and (args.jobs == 1 or len(args.data) == 1)
               and args.scheduler is None}
    note = black_box_note(options)
    document = partial(_document, black_box=note)
    if len(args.data) == 1 and args.scheduler is None:
        outcome = diagnose_file(args.data[0], options)  # errors go to rig.cli with their code
        if args.json:
            print(json.dumps(document(outcome)))
        else:
            _print_summary(args.data[0], args.model, args.noise_bound, *outcome, black_box=note)
        return exit_codes.SUCCESS
    # a cluster's workers do not write into this machine's file system: there, the figures are drawn here
    draw_here = args.scheduler is not None and args.report is not None
    outcomes = map_files(partial(diagnose_file, options={**options, "report": None} if draw_here else options),
                         args.data, jobs=args.jobs, scheduler=args.scheduler,
                         shared_files=[args.model] if args.model is not None else [])
    if draw_here:
        outcomes = [_with_report(outcome, options) for outcome in outcomes]
    if args.json:
        print(json.dumps(batch_document([outcome.to_json("diagnosis", document) for outcome in outcomes])))
    else:
        for outcome in outcomes:
            if outcome.error is None:
                _print_summary(outcome.path, args.model, args.noise_bound, *outcome.result, black_box=note)
            else:
                print(f"data          {outcome.path}\nerror         {outcome.error}")
            print()
    return exit_codes.SUCCESS if all(outcome.error is None for outcome in outcomes) else exit_codes.BAD_INPUT


def _refuse_shared_report_names(paths: list[str]) -> None:
    """With several files, each report goes to DIR/<file name without suffix>/: two files of one name (in
    different directories, or run.csv and run.mf4) would write one report over the other (one file given
    twice writes the same report twice)."""
    if len(paths) < 2:
        return
    seen: dict[str, str] = {}
    for path in paths:
        stem = Path(path).stem
        if stem in seen and Path(seen[stem]).resolve() != Path(path).resolve():
            raise ValueError(f"--report: {seen[stem]} and {path} would both write their report to DIR/{stem}/, one "
                             "over the other; rename one of them, or diagnose them in two commands with two --report "
                             "directories")
        seen[stem] = path


def diagnose_file(path_text: str, options: dict):
    """Diagnose one file with the command's options; return the result, the number of samples, the
    report's index page (None without --report), what the import did and the samples set aside (unusable by
    their flags: left out of the disagreement and the fits, see :func:`identify.model_discrepancy.diagnose_model`).
    A module-level function returning picklable values, so that it runs in other processes."""
    from identify.model_discrepancy import diagnose_model
    from identify.validation import InvalidInputError
    from rig.log_file import check_output_varies, unusable_as_missing
    from rig.record_import import read_measurement

    record, imported = read_measurement(path_text, options.get("import"))
    angle_rad, set_aside = unusable_as_missing(record)
    check_output_varies(path_text, angle_rad)
    model, candidates = _start_model(options, record.metadata.sample_period_s)
    progress = _progress_lines(path_text, record.command_rad.size) if options.get("progress") else None
    try:
        result = diagnose_model(record.command_rad, angle_rad, options["noise_bound"],
                                record.metadata.sample_period_s, model, candidates=candidates,
                                drive_torque=record.drive_torque,
                                drive_torque_nm_per_unit=_torque_scale(record, options.get("torque_scale")),
                                progress=progress)
    except InvalidInputError as err:
        raise InvalidInputError(f"{path_text}: {err}") from err
    index = None
    if options["report"] is not None:
        index = _write_report(path_text, result, record, options)
    return result, int(record.command_rad.size), index, imported, set_aside


def _torque_scale(record, given: float | None = None) -> float | None:
    """N m per unit of the record's torque column: ``given`` (``--torque-scale``), else where a rig log's summary
    gives it, else None."""
    if given is not None:
        return given if record.drive_torque is not None else None
    summary = record.metadata.extra.get("summary")
    scale = summary.get("drive_torque_nm_per_unit") if isinstance(summary, dict) else None
    return None if record.drive_torque is None or not isinstance(scale, (int, float)) or scale <= 0 else float(scale)


def _write_report(path_text: str, result, record, options: dict):
    """The figures and HTML page of one file's diagnosis under ``--report``; returns the index page."""
    from rig.output_paths import writing
    from rig.plots.discrepancy import write_discrepancy_report

    directory = Path(options["report"])
    if options["report_per_file"]:
        directory = directory / Path(path_text).stem
    with writing(directory, "--report"):
        return write_discrepancy_report(directory, result, record.command_rad, record.angle_rad,
                                        record.metadata.sample_period_s, source=str(path_text))


def _with_report(outcome, options: dict):
    """A file diagnosed on a cluster worker, with its report drawn here from the file read again."""
    import dataclasses

    from rig.record_import import read_measurement

    if outcome.error is not None:
        return outcome
    result, num_samples, _, imported, set_aside = outcome.result
    record, _ = read_measurement(outcome.path, options.get("import"))
    index = _write_report(outcome.path, result, record, options)
    return dataclasses.replace(outcome, result=(result, num_samples, index, imported, set_aside))


def _fmu_options(args: argparse.Namespace) -> dict | None:
    """For ``--model PLANT.fmu``: check the FMU before any work (file, variables, platform binary) and return
    what the workers need to open it again; None for a plant TOML or no model. ``--fmu-input`` /
    ``--fmu-output`` without an FMU are refused."""
    from rig.protocols.errors import ConfigError
    from sim_backend.fmu_plant import is_fmu_path, open_fmu_block, parse_parameter_assignments

    if args.model is None or not is_fmu_path(args.model):
        for option, value in (("--fmu-input", args.fmu_input), ("--fmu-output", args.fmu_output),
                              ("--fmu-parameter", args.fmu_parameter or None)):
            if value is not None:
                what = "sets a parameter" if option == "--fmu-parameter" else "chooses a variable"
                raise ConfigError(option, "--model", f"{option} {what} of an FMU: give --model PLANT.fmu")
        return None
    parameters = parse_parameter_assignments(args.fmu_parameter)
    block = open_fmu_block(args.model, 1.0, args.fmu_input, args.fmu_output,  # the period is each file's
                           parameters=parameters, parameters_key="--fmu-parameter")
    return {"input": block.input_name, "output": block.output_name, "parameters": parameters}


def _start_model(options: dict, sample_period_s: float):
    """The start model of ``--model`` and the candidate effects: a plant TOML's blocks and every effect; an
    FMU as one black-box block (:mod:`sim_backend.fmu_plant`) sampled at the record's period and the effects
    that can be added around it (:func:`identify.black_box_effects.effects_around_black_box`); no model: a
    fitted linear model (None) and every effect (every searched one: an effect tried only as the look-alike of a
    named one is not, :data:`identify.effect_catalogue.SEARCHED_EFFECT_NAMES`)."""
    from identify.effect_catalogue import SEARCHED_EFFECT_NAMES
    from rig.batch import shipped_path

    if options["model"] is None:
        return None, SEARCHED_EFFECT_NAMES
    if options.get("fmu") is None:
        from sim_backend.plant_config import load_plant_config

        return load_plant_config(shipped_path(options["model"])).plant, SEARCHED_EFFECT_NAMES  # a cluster worker's copy
    from identify.black_box_effects import effects_around_black_box
    from identify.plant_blocks import PlantModel
    from sim_backend.fmu_plant import open_fmu_block

    block = open_fmu_block(shipped_path(options["model"]), sample_period_s, options["fmu"]["input"],
                           options["fmu"]["output"], parameters=options["fmu"].get("parameters"),
                           parameters_key="--fmu-parameter")
    candidates, _ = effects_around_black_box()
    return PlantModel((block,)), candidates


def black_box_note(options: dict) -> dict | None:
    """What ``--json`` and the text output say about an FMU start model: the file, its input and output, the
    effects tried around it (and where they go) and those skipped with the reason; None without an FMU."""
    if options.get("fmu") is None:
        return None
    from identify.black_box_effects import effects_around_black_box, placements_text

    tried, skipped = effects_around_black_box()
    return {"file": str(options["model"]), "input": options["fmu"]["input"], "output": options["fmu"]["output"],
            "parameters": dict(options["fmu"].get("parameters") or {}),
            "effects_tried": placements_text(tried), "effects_skipped": skipped}


def _progress_lines(path_text: str, num_samples: int):
    """On a terminal: a line on stderr for each step of the diagnosis, with the time since it began (a
    record of 20 000 samples takes about two minutes; the time grows about linearly with the samples)."""
    import sys
    import time

    started = time.monotonic()
    print(f"rig: diagnosing {path_text} ({num_samples} samples; each step below is one fit)", file=sys.stderr,
          flush=True)

    def say(message: str) -> None:
        print(f"  [{time.monotonic() - started:5.0f} s] {message.strip()}", file=sys.stderr, flush=True)

    return say


def _document(outcome, black_box: dict | None = None) -> dict:
    """The ``--json`` object of one file: the result's document plus what the import did (and, for an FMU
    start model, ``fmu``: :func:`black_box_note`)."""
    result, _, _, imported, set_aside = outcome
    document = {**result.to_dict(), "import": imported.to_dict(), "set_aside": set_aside.to_dict()}
    if black_box is not None:
        document["fmu"] = black_box
    return document


def _acceptance_note(candidate) -> str:
    """What a candidate's gap reduction said (``identify.model_discrepancy.ACCEPTANCES``), for the candidates
    line: vanished, or the reduction with the interval judged and its parts when it reaches the acceptance (the
    validated reduction may lie outside the refits' interval that named the effect)."""
    if candidate.vanished:
        return " (vanished)"
    if candidate.acceptance in ("clear", "undecided"):
        return f" ({candidate.acceptance}: reduction {candidate.reduction_text()})"
    return ""


def _print_summary(data: str, model: str | None, noise_bound: float, result, num_samples: int, index,
                   imported=None, set_aside=None, black_box: dict | None = None) -> None:
    print(f"data          {data}  ({num_samples} samples, validation from sample "
          f"{result.estimation_samples})")
    if set_aside is not None and set_aside.samples:
        print(f"set aside     {set_aside.samples} of {set_aside.total} samples, unusable by their flags "
              f"({set_aside.flags_text()}): the free run covers them, the disagreement and the fits leave them out")
    start = model or ("linear, order %d (fitted)" % result.linear_fit.order if result.linear_fit else "not fitted")
    for note in (imported.notes if imported is not None else ()):
        print(f"import        {note}")
    if result.operating_point_rad:
        print(f"operating pt  {result.operating_point_rad:.4g} rad (the first command: the free run starts at rest "
              "there)")
    print(f"start model   {start}")
    if black_box is not None:
        print(f"fmu           input {black_box['input']!r}, output {black_box['output']!r}: effects are added "
              "around it (input side: before its input; output side: after its output)")
        if black_box.get("parameters"):
            print("fmu params    " + ", ".join(f"{name} = {value!r}" for name, value in black_box["parameters"].items()))
        for name, reason in black_box["effects_skipped"].items():
            print(f"not tried     {name}: {reason}")
    print(f"noise bound   {noise_bound:.4g} rad")
    from rig.plots.discrepancy import VERDICT_WORDS

    print(f"verdict       {VERDICT_WORDS[result.verdict]}")
    print(f"              {result.verdict_reason}")
    for finding in result.findings:  # measurement-side: the record disagrees with itself there
        print(f"measurement   {finding.text()}")
    print(f"initial gap   {result.initial.gap_rad:.4g} rad, {100 * result.initial.falsified_fraction:.1f} % "
          f"of validation samples falsified, {len(result.initial.windows)} disagreement windows")
    rounds = sorted({c.round for c in result.candidates})
    for round_index in rounds:
        tried = sorted((c for c in result.candidates if c.round == round_index), key=lambda c: c.penalised_gap_rad)
        print(f"candidates {round_index + 1}  " + "; ".join(
            f"{c.effect} {c.gap_rad:.3g} +- {c.gap_uncertainty_rad:.2g}" + _acceptance_note(c) for c in tried) + " rad")
    for number, step in enumerate(result.steps, 1):
        intervals = result.parameter_intervals.get(step.effect, {})
        parameters = ", ".join(
            f"{k} = {v:.4g}" + (f" [{intervals[k][0]:.4g}, {intervals[k][1]:.4g}]" if k in intervals else "")
            for k, v in step.parameters.items())
        print(f"step {number}: {step.effect:<17} gap {step.gap_before_rad:.4g} -> {step.gap_after_rad:.4g} rad  "
              f"({parameters})")
    for candidate in result.undecided:
        print(f"undecided     {candidate.effect}: gap {candidate.gap_rad:.4g} rad, reduction "
              f"{candidate.reduction_text()}, within its uncertainty around the acceptance: not named")
    if not result.steps and result.undecided:
        print(f"no effect named ({', '.join(c.effect for c in result.undecided)} undecided)")
    elif not result.steps:
        print("no missing effect found" if result.verdict != "ambiguous" else
              f"no effect chosen between {', '.join(result.ambiguous_between)}")
    elif result.verdict == "ambiguous" and set(result.ambiguous_between) & set(result.missing_effects):
        print(f"mechanism     not told: {' or '.join(result.ambiguous_between)}, one map from command to angle")
    elif result.verdict == "ambiguous" and result.ambiguous_between and not result.undecided:
        print(f"then          no effect chosen between {', '.join(result.ambiguous_between)}")
    print(f"final gap     {result.final.gap_rad:.4g} rad, {100 * result.final.falsified_fraction:.1f} % falsified")
    if result.steps and result.gap_reduction:
        print(f"gap reduction {100 * result.gap_reduction_fraction:.1f} % on the validation segment, "
              f"{100 * result.gap_reduction['low']:.1f} .. {100 * result.gap_reduction['high']:.1f} % over "
              f"{len(result.gap_reduction['folds'])} cross-validation folds")
    print(result.unexplained)
    structure = result.residual_structure
    if structure is not None:
        print(f"open world    a black box of the command, the model's output and its angle predicts "
              f"{100 * structure.explained_fraction:.0f} % of what the final model leaves on held-out samples "
              f"(gap {structure.gap_rad:.3g} -> {structure.gap_after_black_box_rad:.3g} rad)")
    if index is not None:
        print(f"report        {index}")
