"""``rig import TRACE --config RIG.toml --out LOG``: a CAN trace of a rig run as a rig log
(:mod:`rig.trace_import`)."""

from __future__ import annotations

import argparse
import json

from rig import exit_codes

DESCRIPTION = """\
Decode a CAN trace of a run into a rig-log v1 file, every sample accounted for, by the transport of RIG.toml:

  can://      sample k is the k-th RIG_SETPOINT (configs/raw_can.dbc or the config's dbc), its reading the
              RIG_FEEDBACK + RIG_DRIVE_FEEDBACK (v3: RIG_DRIVE_TICK) pair with the same sequence number (LOST
              where it is missing or came more than 4 setpoints late, DUPLICATE, FAULT; on a device-clocked rig
              HELD with the target in force); LATE from the trace's time stamps (host-paced rigs)
  canopen://  the PDOs decoded by the mapping of the run (--dcf files, else the SDO writes of the trace's
              start-up, another master's too, else the one this driver sets up; node-IDs from the config):
              sample 0's SYNC is the one after the first target (0x607A or 0x60C1:01) to the drive; each TPDO
              (0x6041, 0x6062, the encoder's 0x6004) is filed under the last SYNC before its time stamp; HELD
              where the target in force at a SYNC is an earlier sample's, LATE where the SYNC spacing is off

The trace of `rig run --can-trace run.blf` gives back the log the run wrote (raw CAN: LATE apart, which the
run judged on the host's clock). TRACE is read with python-can's readers, chosen by suffix: .blf (Vector
CANalyzer/CANoe), .asc, .trc (PEAK PCAN-View), .log (candump -l), .csv (python-can)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "import",
        help="decode a CAN trace (BLF, ASC, TRC, candump) of a raw-CAN or CANopen run into a rig log",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("trace", metavar="TRACE", help="CAN trace: .blf, .asc, .trc, .log (candump -l) or .csv")
    parser.add_argument("--config", metavar="RIG.toml", required=True,
                        help="the rig config of the run (rate, drive scaling, encoder, DBC or node-IDs)")
    parser.add_argument("--out", metavar="LOG", required=True,
                        help="log file to write (CSV, rig-log v1); an existing file is refused unless --force")
    parser.add_argument("--force", action="store_true", help="replace an existing --out file")
    parser.add_argument("--dcf", metavar="NODE=FILE", action="append", default=[],
                        help="CANopen: the DCF (or EDS) of node-ID NODE, whose PDO mapping (0x1400-0x1BFF) decodes a "
                             "trace that starts after the start-up; repeat for each node. Without it the mapping "
                             "is read from the trace's own SDO writes, else this program's master's is assumed")
    parser.add_argument("--json", action="store_true",
                        help='print {"log", "trace", "samples", "lost", "late", "held", "duplicate", "fault", '
                             '"frame_errors", "pdo_mapping"} as JSON')
    parser.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from identify.experiment_record import SampleFlag
    from rig.log_file import write_log
    from rig.output_paths import atomic_output, check_output_file
    from rig.rig_config import load_rig_config
    from rig.trace_import import import_trace

    dcf = {}
    for given in args.dcf:
        node, _, path = given.partition("=")
        if not node.strip().isdigit() or not path or not 1 <= int(node) <= 127:
            raise ValueError(f"--dcf {given}: expected NODE=FILE with a node-ID from 1 to 127, e.g. --dcf 3=drive.dcf")
        dcf[int(node)] = path
    check_output_file(args.out, "--out", inputs=[args.trace, args.config, *dcf.values()], force=args.force)
    config = load_rig_config(args.config)
    record = import_trace(args.trace, config, dcf=dcf or None)
    with atomic_output(args.out, "--out", force=args.force) as written:
        write_log(written, record)
    result = {"log": args.out, "trace": args.trace, "samples": len(record),
              **{name: record.count_flag(flag) for name, flag in (
                  ("lost", SampleFlag.LOST), ("late", SampleFlag.LATE), ("held", SampleFlag.HELD),
                  ("duplicate", SampleFlag.DUPLICATE),
                  ("fault", SampleFlag.FAULT))},
              "frame_errors": record.metadata.extra["summary"]["frame_errors"],
              **({"pdo_mapping": record.metadata.extra["imported_from"]["pdo_mapping"]}
                 if "pdo_mapping" in record.metadata.extra["imported_from"] else {})}
    if args.json:
        print(json.dumps(result))
    else:
        width = max(len(key) for key in result)
        for key, value in result.items():
            print(f"{key:<{width}}  {value}")
    return exit_codes.SUCCESS
