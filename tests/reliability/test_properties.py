"""Property-based tests (hypothesis) for hostile input to the readers.

* Serial decoder (``rig.protocols.serial_frames.FrameDecoder``): arbitrary byte streams never raise and only
  ever yield messages whose frame, CRC included, is on the wire between two delimiters; valid frames after
  garbage that ends with a 0x00 delimiter are all recovered, however the stream is split into reads.
* Log reader (``rig.log_file.read_log`` / ``read_experiment_data``): a valid log, damaged (truncated, bytes
  flipped, junk lines inserted), either reads back as a prefix of the original samples or raises a
  ``ValueError`` (``LogFileError`` / ``InvalidInputError``) whose message names the file.
* Config loaders (``sim_backend.plant_config``, ``rig.rig_config``): arbitrary TOML documents and mutations
  of the shipped configs give a valid config or a ``ConfigError`` naming the file and the key.
"""

from __future__ import annotations

import itertools
import math
import shutil
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from identify.validation import InvalidInputError
from rig.log_file import LogWriter, read_experiment_data, read_log
from rig.protocols.errors import ConfigError, LogFileError
from rig.protocols.serial_frames import (
    MAX_PAYLOAD,
    FrameDecoder,
    MessageType,
    SerialMessage,
    cobs_decode,
    crc16,
    decode_frame,
    encode_frame,
)
from rig.rig_config import load_rig_config
from sim_backend.plant_config import (
    PlantConfig,
    load_plant_config,
    plant_config_from_toml_text,
)

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
FAST = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
SLOW = settings(max_examples=50, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# ----------------------------------------------------------------------------------------------------------
# Serial decoder
# ----------------------------------------------------------------------------------------------------------

_FIELD_RANGES = {  # struct formats of the bodies in serial_frames._BODY_FORMATS
    MessageType.SETPOINT: [(-2**31, 2**31 - 1)],
    MessageType.CONTROL: [(0, 0xFFFF)],
    MessageType.STATUS_REQUEST: [],
    MessageType.FEEDBACK: [(0, 0xFFFF), (-2**31, 2**31 - 1), (0, 2**32 - 1)],
    MessageType.STATUS: [(0, 0xFFFF), (-2**31, 2**31 - 1)],
    MessageType.FAULT: [(0, 0xFFFF)],
    MessageType.ERROR_REQUEST: [],
    MessageType.ERROR: [(0, 0xFFFF)],
    MessageType.HELLO: [(0, 0xFF)],
    MessageType.START: [],
    MessageType.DEVICE_INFO: [(0, 0xFF), (0, 0xFFFF), (0, 2**32 - 1)],
    MessageType.TICK: [(0, 0xFFFF), (-2**31, 2**31 - 1), (0, 2**32 - 1), (-2**31, 2**31 - 1), (0, 0xFF), (0, 0xFFFF)],
}


@st.composite
def messages(draw: st.DrawFn) -> SerialMessage:
    kind = draw(st.sampled_from(list(MessageType)))
    seq = draw(st.integers(0, 0xFFFF))
    fields = tuple(draw(st.integers(low, high)) for low, high in _FIELD_RANGES[kind])
    return SerialMessage(kind, seq, fields)


def _wire(message: SerialMessage) -> bytes:
    return encode_frame(message.type, message.seq, *message.fields)


@st.composite
def split_points(draw: st.DrawFn, data: bytes) -> list[bytes]:
    """``data`` cut into consecutive reads at arbitrary points (as a serial port returns it)."""
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=8)))
    bounds = [0, *cuts, len(data)]
    return [data[a:b] for a, b in itertools.pairwise(bounds)]


def _feed_all(decoder: FrameDecoder, reads: list[bytes]) -> list[SerialMessage]:
    out: list[SerialMessage] = []
    for chunk in reads:
        out += decoder.feed(chunk)
    return out


def _reference(stream: bytes) -> tuple[list[SerialMessage], int]:
    """What docs/serial_protocol.md ("Resynchronisation") specifies for a stream read in one piece: every
    non-empty 0x00-delimited chunk that passes COBS, CRC, type and length checks is a message, every other
    one an error; a tail without a delimiter waits (or is dropped as one error beyond 2 * MAX_PAYLOAD)."""
    *chunks, tail = stream.split(b"\x00")
    good: list[SerialMessage] = []
    errors = 0
    for chunk in chunks:
        if not chunk:
            continue
        try:
            good.append(decode_frame(chunk))
        except ValueError:
            errors += 1
    if len(tail) > 2 * MAX_PAYLOAD:
        errors += 1
    return good, errors


def _crc_ok_on_wire(message: SerialMessage, stream: bytes) -> bool:
    """The message's frame, CRC included, is in ``stream`` followed by a delimiter, and its CRC checks."""
    encoded = _wire(message)[:-1]
    raw = cobs_decode(encoded)
    return crc16(raw[:-2]) == int.from_bytes(raw[-2:], "little") and encoded + b"\x00" in stream


@FAST
@given(stream=st.binary(max_size=600), data=st.data())
def test_serial_decoder_survives_arbitrary_bytes(stream: bytes, data: st.DataObject) -> None:
    decoder = FrameDecoder()
    reads = data.draw(split_points(stream))
    got = _feed_all(decoder, reads)  # must not raise
    for message in got:
        assert isinstance(message, SerialMessage)
        assert _crc_ok_on_wire(message, stream), message
    # Read in one piece, the decoder does exactly what the protocol page specifies.
    whole = FrameDecoder()
    assert whole.feed(stream) == _reference(stream)[0]
    assert whole.errors == _reference(stream)[1]


@FAST
@given(stream=st.lists(st.one_of(messages().map(_wire), st.binary(max_size=40)), max_size=12).map(b"".join),
       data=st.data())
def test_serial_decoder_mixed_frames_and_garbage_never_yields_bad_crc(stream: bytes, data: st.DataObject) -> None:
    """Garbage glued to frames (no delimiter in between) spoils at most the frames it touches."""
    got = _feed_all(FrameDecoder(), data.draw(split_points(stream)))
    assert all(_crc_ok_on_wire(message, stream) for message in got)


@FAST
@given(pieces=st.lists(st.tuples(st.binary(max_size=300), st.lists(messages(), max_size=4)), min_size=1, max_size=5),
       data=st.data())
def test_serial_decoder_recovers_every_frame_after_garbage_ending_in_a_delimiter(
        pieces: list[tuple[bytes, list[SerialMessage]]], data: st.DataObject) -> None:
    """The guarantee of docs/serial_protocol.md: after any garbage, the receiver starts afresh after the next
    0x00, so every valid frame that follows garbage terminated by 0x00 is decoded, in order, whatever the
    garbage (longer than 128 bytes or not) and however the stream is split into reads. Garbage may itself
    happen to hold valid frames; the sent frames must be an in-order subsequence of what is decoded."""
    stream = b"".join(garbage + b"\x00" + b"".join(_wire(m) for m in frames) for garbage, frames in pieces)
    sent = [m for _, frames in pieces for m in frames]
    decoder = FrameDecoder()
    got = _feed_all(decoder, data.draw(split_points(stream)))
    remaining = iter(got)
    assert all(any(m == g for g in remaining) for m in sent), (sent, got)
    garbage_only = b"".join(garbage + b"\x00" for garbage, _ in pieces)
    assert len(got) - len(sent) <= len(_reference(garbage_only)[0])


# ----------------------------------------------------------------------------------------------------------
# Log reader
# ----------------------------------------------------------------------------------------------------------

N_SAMPLES = 12


def _original_log(path: Path) -> dict[str, np.ndarray]:
    period = 0.001
    k = np.arange(N_SAMPLES)
    values = {
        "time_s": k * period,
        "command_rad": np.sin(0.7 * k) * 0.25,
        "angle_rad": np.where(k == 5, np.nan, np.cos(0.3 * k) * 0.1),
        "encoder_counts": (k * 37 - 100),
        "flags": np.where(k == 5, 1, 0),
    }
    with LogWriter(path, {"sample_period_s": period, "source": "hypothesis", "noise_bound_rad": 0.001}) as log:
        log.append_many(values["time_s"], values["command_rad"], values["angle_rad"], values["encoder_counts"],
                        values["flags"])
    return values


def _line_starts(raw: bytes) -> list[int]:
    return [0] + [i + 1 for i, byte in enumerate(raw) if byte == 0x0A]


def _check_read(path: Path, original: dict[str, np.ndarray], reader, touched_samples: set[int]) -> None:
    """``reader(path)`` returns the original samples (a prefix; samples on damaged lines may differ) or raises
    a ValueError naming the file; never anything else."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            record = reader(path)
    except (LogFileError, InvalidInputError) as err:
        assert str(path) in str(err), str(err)
        return
    n = len(record)
    assert 1 <= n <= N_SAMPLES
    keep = [i for i in range(n) if i not in touched_samples]
    np.testing.assert_array_equal(record.time_s[keep], original["time_s"][keep])
    np.testing.assert_array_equal(record.command_rad[keep], original["command_rad"][keep])
    np.testing.assert_array_equal(record.angle_rad[keep], original["angle_rad"][keep])  # NaN == NaN here
    np.testing.assert_array_equal(record.flags[keep], original["flags"][keep])
    if record.encoder_counts is not None:
        lost = original["flags"][keep] != 0
        expected = np.where(lost, 0, original["encoder_counts"][keep])
        np.testing.assert_array_equal(record.encoder_counts[keep], expected)


READERS = [read_log, read_experiment_data]


@SLOW
@pytest.mark.parametrize("reader", READERS, ids=lambda f: f.__name__)
@given(cut=st.integers(0, 10_000))
def test_truncated_log_reads_a_prefix_or_names_the_file(tmp_path: Path, reader, cut: int) -> None:
    path = tmp_path / "run.log"
    original = _original_log(path)
    raw = path.read_bytes()
    path.write_bytes(raw[:cut % (len(raw) + 1)])
    _check_read(path, original, reader, touched_samples=set())


@SLOW
@pytest.mark.parametrize("reader", READERS, ids=lambda f: f.__name__)
@given(flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), min_size=1, max_size=4))
def test_byte_flipped_log_keeps_undamaged_samples_or_names_the_file(tmp_path: Path, reader,
                                                                   flips: list[tuple[int, int]]) -> None:
    """rig-log v1 has no per-line checksum, so a flipped digit on a data line can change that sample's value
    undetected (``0.25`` -> ``0.35``); every sample on an undamaged line must come back unchanged."""
    path = tmp_path / "run.log"
    original = _original_log(path)
    raw = bytearray(path.read_bytes())
    header_lines = 4
    starts = _line_starts(bytes(raw))
    touched: set[int] = set()
    for position, value in flips:
        position %= len(raw)
        raw[position] = value
        line = max(i for i, start in enumerate(starts) if start <= position)
        touched.add(line - header_lines)
    path.write_bytes(bytes(raw))
    _check_read(path, original, reader, touched_samples=touched)


def _looks_like_a_sample_row(line: str) -> bool:
    fields = line.split(",")
    if len(fields) != 5:
        return False
    try:
        [float(text) for text in fields[:3]]
        [int(text) for text in fields[3:] if text.strip()]
    except ValueError:
        return False
    return True


@SLOW
@pytest.mark.parametrize("reader", READERS, ids=lambda f: f.__name__)
@given(junk=st.lists(st.tuples(st.integers(0, 100), st.text(st.characters(codec="utf-8", exclude_characters="\n"), max_size=30)),
                     min_size=1, max_size=3))
def test_log_with_junk_lines_reads_a_prefix_or_names_the_file(tmp_path: Path, reader,
                                                              junk: list[tuple[int, str]]) -> None:
    """A junk line that is not itself a well-formed sample row (those cannot be told from data) ends the
    readable data at a named line, or (a ``#`` line in the header) is ignored."""
    assume(not any(_looks_like_a_sample_row(text.rstrip("\r")) for _, text in junk))
    path = tmp_path / "run.log"
    original = _original_log(path)
    lines = path.read_text(encoding="utf-8").split("\n")
    for position, text in junk:
        lines.insert(position % len(lines), text)
    path.write_text("\n".join(lines), encoding="utf-8", newline="\n")
    _check_read(path, original, reader, touched_samples=set())


_METADATA_FIELDS = ["sample_period_s", "source", "transport", "encoder_bits", "noise_kind", "noise_bound_rad",
                    "excitation", "excitation_seed", "seed", "config", "software_version", "extra", "unknown"]
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=3),
    max_leaves=6)


@SLOW
@given(changes=st.dictionaries(st.sampled_from(_METADATA_FIELDS), json_values, min_size=1, max_size=4)
       | json_values.filter(lambda value: not isinstance(value, dict)))
def test_log_with_bad_metadata_reads_or_names_the_file(tmp_path: Path, changes) -> None:
    """Well-formed JSON of the wrong shape on the metadata line (a field of the wrong type, ``"extra": "ab"``,
    a list instead of an object) is a LogFileError naming the file, never a bare ValueError or TypeError."""
    import json

    path = tmp_path / "run.log"
    original = _original_log(path)
    lines = path.read_text(encoding="utf-8").split("\n")
    if isinstance(changes, dict):
        metadata = json.loads(lines[1][len("# metadata "):])
        metadata.update(changes)
    else:
        metadata = changes
    lines[1] = "# metadata " + json.dumps(metadata)
    path.write_text("\n".join(lines), encoding="utf-8", newline="\n")
    _check_read(path, original, read_log, touched_samples=set())


# ----------------------------------------------------------------------------------------------------------
# Config loaders
# ----------------------------------------------------------------------------------------------------------


def _toml_string(text: str) -> str:
    out = []
    for char in text:
        if char in '"\\':
            out.append("\\" + char)
        elif ord(char) < 0x20 or ord(char) == 0x7F:
            out.append(f"\\u{ord(char):04X}")
        else:
            out.append(char)
    return '"' + "".join(out) + '"'


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else ("inf" if value > 0 else "-inf"))
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_string(key)} = {_toml_value(item)}" for key, item in value.items()) + "}"
    raise TypeError(type(value))


def dump_toml(document: dict) -> str:
    """A tiny TOML writer for the shapes generated here: scalars and arrays as ``key = value``, tables as
    ``[table]`` sections (nested tables inline), arrays of tables as ``[[key]]`` sections."""
    head, tail = [], []
    for key, value in document.items():
        if isinstance(value, dict):
            tail.append(f"\n[{_toml_string(key)}]")
            tail += [f"{_toml_string(k)} = {_toml_value(v)}" for k, v in value.items()]
        elif isinstance(value, list) and value and all(isinstance(item, dict) for item in value):
            for item in value:
                tail.append(f"\n[[{_toml_string(key)}]]")
                tail += [f"{_toml_string(k)} = {_toml_value(v)}" for k, v in item.items()]
        else:
            head.append(f"{_toml_string(key)} = {_toml_value(value)}")
    return "\n".join(head + tail) + "\n"


_KEYS = ["name", "description", "sample_period_s", "sample_rate_hz", "seed", "encoder", "bits", "multi_turn_bits",
         "signed", "direction", "offset_counts", "noise", "kind", "bound_rad", "std_rad", "snr_db", "numerator",
         "denominator", "blocks", "type", "enabled", "a", "b", "A", "B", "C", "D", "samples", "lower_rad",
         "upper_rad", "left_rad", "right_rad", "m_l", "c_l_rad", "m_r", "c_r_rad", "ascending", "descending", "nodes_u",
         "values", "input_shift_rad", "frequency_hz", "damping_ratio", "offset_rad", "gain", "breakaway_torque_nm",
         "coulomb_torque_nm", "stiffness_nm_per_rad", "transport", "url", "drive", "counts_per_revolution",
         "limits", "position_min_rad", "position_max_rad", "rate_max_rad_per_s", "watchdog", "feedback_timeout_s",
         "late_tolerance_s", "simulation", "plant", "baudrate", "reply_timeout_s"]
_WORDS = ["linear", "delay", "saturation", "dead_zone", "resonance", "offset", "gain", "output_backlash", "input_backlash",
          "input_switch", "state_space", "coulomb_friction", "table", "arctan", "uniform", "gaussian", "coloured",
          "quantization", "serial://pty", "can://virtual/x", "canopen://virtual/x", "plants/cerone2009.toml"]
keys = st.sampled_from(_KEYS) | st.text(st.characters(codec="utf-8"), min_size=1, max_size=8)
scalars = (st.booleans() | st.integers(-2**63, 2**63 - 1) | st.integers(-3, 40)
           | st.floats(allow_nan=True, allow_infinity=True) | st.sampled_from([0.0, 0.001, 0.5, 1.0, 1000.0, -1.0])
           | st.sampled_from(_WORDS) | st.text(st.characters(codec="utf-8"), max_size=10))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(keys, inner, max_size=4),
                      max_leaves=12)
documents = st.dictionaries(keys, values | st.lists(st.dictionaries(keys, values, max_size=5), min_size=1, max_size=3),
                            max_size=8)


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def _assert_named_config_error(err: ConfigError, source: str) -> None:
    assert err.source == source
    assert err.key, str(err)
    assert str(err).startswith(f"{source}: [{err.key}] "), str(err)


def _load_plant_text(text: str, source: str) -> None:
    try:
        config = plant_config_from_toml_text(text, source=source)
    except ConfigError as err:
        _assert_named_config_error(err, source)
        return
    assert isinstance(config, PlantConfig)
    assert config.sample_period_s > 0 and config.blocks


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(document=documents)
def test_arbitrary_toml_gives_a_plant_config_or_a_named_config_error(document: dict) -> None:
    text = dump_toml(document)
    assert _same(tomllib.loads(text), document)  # the tiny writer is right
    _load_plant_text(text, "fuzz.toml")


@pytest.fixture(scope="module")
def config_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of configs/ (rig configs point at plants by relative path)."""
    root = tmp_path_factory.mktemp("configs") / "configs"
    shutil.copytree(CONFIGS, root)
    return root


def _paths(document, prefix=()):  # every (path to a value) in a parsed TOML document
    if isinstance(document, dict):
        for key, value in document.items():
            yield (*prefix, key)
            yield from _paths(value, (*prefix, key))
    elif isinstance(document, list):
        for index, value in enumerate(document):
            if isinstance(value, dict):
                yield from _paths(value, (*prefix, index))


def _parent(document, path):
    for part in path[:-1]:
        document = document[part]
    return document


@st.composite
def mutated(draw: st.DrawFn, document: dict) -> dict:
    """The shipped document with one to three changes: a key dropped, a value replaced by one of another
    type (or any value), an unknown key added."""
    import copy

    document = copy.deepcopy(document)
    for _ in range(draw(st.integers(1, 3))):
        paths = list(_paths(document))
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = _parent(document, path)
        action = draw(st.sampled_from(["drop", "retype", "add"]))
        if action == "drop":
            del parent[path[-1]]
        elif action == "retype":
            parent[path[-1]] = draw(values)
        else:
            target = parent if isinstance(parent, dict) else document
            target[draw(keys)] = draw(values)
    return document


SHIPPED_PLANTS = sorted(p.name for p in (CONFIGS / "plants").glob("*.toml"))
SHIPPED_RIGS = sorted(p.name for p in CONFIGS.glob("*.toml"))


@SLOW
@pytest.mark.parametrize("name", SHIPPED_PLANTS)
@given(data=st.data())
def test_mutated_plant_config_is_valid_or_a_named_config_error(config_copy: Path, name: str,
                                                               data: st.DataObject) -> None:
    shipped = tomllib.loads((CONFIGS / "plants" / name).read_text(encoding="utf-8"))
    document = data.draw(mutated(shipped))
    path = config_copy / "plants" / f"mutated_{name}"
    path.write_text(dump_toml(document), encoding="utf-8")
    try:
        config = load_plant_config(path)
    except ConfigError as err:
        _assert_named_config_error(err, str(path))
        return
    assert isinstance(config, PlantConfig) and config.blocks


@SLOW
@pytest.mark.parametrize("name", SHIPPED_RIGS)
@given(data=st.data())
def test_mutated_rig_config_is_valid_or_a_named_config_error(config_copy: Path, name: str,
                                                             data: st.DataObject) -> None:
    shipped = tomllib.loads((CONFIGS / name).read_text(encoding="utf-8"))
    document = data.draw(mutated(shipped) | documents)
    path = config_copy / f"mutated_{name}"
    path.write_text(dump_toml(document), encoding="utf-8")
    try:
        config = load_rig_config(path)
    except ConfigError as err:
        _assert_named_config_error(err, str(path))
        return
    assert config.sample_rate_hz > 0 and config.limits is not None


def _outcome(load, path: Path) -> tuple[str, str]:
    try:
        load(path)
    except ConfigError as err:
        return "error", f"[{err.key}] {err.problem}"
    return "ok", ""


def test_shipped_configs_load_the_same_through_the_tiny_writer(config_copy: Path) -> None:
    """The shipped configs, rewritten by dump_toml next to the originals, load exactly as the originals do
    (all valid except the rig_canopen.toml template, whose EDS paths are placeholders): the mutation tests
    start from the shipped input."""
    outcomes = {}
    for load, folder, names in ((load_plant_config, config_copy / "plants", SHIPPED_PLANTS),
                                (load_rig_config, config_copy, SHIPPED_RIGS)):
        for name in names:
            original = folder / name
            rewritten = folder / f"rewritten_{name}"
            rewritten.write_text(dump_toml(tomllib.loads(original.read_text(encoding="utf-8"))), encoding="utf-8")
            outcomes[name] = _outcome(load, original)
            assert _outcome(load, rewritten) == outcomes[name]
    assert {name for name, (kind, _) in outcomes.items() if kind == "error"} == {"rig_canopen.toml"}
    assert outcomes["rig_canopen.toml"][1].startswith("[transport.drive_eds] no such EDS file")
