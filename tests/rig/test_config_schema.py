import pytest

from rig.protocols.config_schema import load_toml
from rig.protocols.errors import ConfigError


def write(tmp_path, text):
    path = tmp_path / "rig.toml"
    path.write_text(text)
    return path


def test_values_are_read_and_checked(tmp_path):
    table = load_toml(write(tmp_path, 'rate_hz = 1000\n[encoder]\nbits = 12\nname = "load"\n'))
    assert table.number("rate_hz", minimum=1) == 1000.0
    encoder = table.table("encoder")
    assert encoder.integer("bits", minimum=1, maximum=32) == 12
    assert encoder.string("name", choices=("load", "motor")) == "load"
    assert encoder.boolean("signed", default=False) is False
    encoder.finish()
    table.finish()


def test_unknown_key_is_named_with_file(tmp_path):
    path = write(tmp_path, "[encoder]\nbits = 12\nbitz = 3\n")
    encoder = load_toml(path).table("encoder")
    encoder.integer("bits")
    with pytest.raises(ConfigError, match=r"rig.toml: \[encoder.bitz\] unknown key \(known keys here: bits\)"):
        encoder.finish()


def test_wrong_type_range_and_missing(tmp_path):
    table = load_toml(write(tmp_path, 'rate_hz = "fast"\nbits = 40\n'))
    with pytest.raises(ConfigError, match=r"\[rate_hz\] expected a finite number, got 'fast'"):
        table.number("rate_hz")
    with pytest.raises(ConfigError, match=r"\[bits\] expected an integer <= 32, got 40"):
        table.integer("bits", maximum=32)
    with pytest.raises(ConfigError, match=r"\[period_s\] is required but missing"):
        table.number("period_s")


def test_invalid_toml_names_file(tmp_path):
    with pytest.raises(ConfigError, match=r"rig.toml: \[<file>\] not valid TOML"):
        load_toml(write(tmp_path, "rate_hz = = 3\n"))


def test_arrays_of_tables_and_matrices(tmp_path):
    table = load_toml(write(tmp_path, 'A = [[1, 2], [3, 4]]\n[[blocks]]\ntype = "delay"\n[[blocks]]\ntype = "gain"\n'))
    blocks = table.tables("blocks")
    assert [block.string("type") for block in blocks] == ["delay", "gain"]
    assert blocks[1].key_path("x") == "blocks[1].x"
    assert table.matrix("A") == [[1.0, 2.0], [3.0, 4.0]]
    table.finish()
    bad = load_toml(write(tmp_path, 'A = [[1, "x"]]\nblocks = 3\n'))
    with pytest.raises(ConfigError, match=r"\[A\] expected a matrix"):
        bad.matrix("A")
    with pytest.raises(ConfigError, match=r"\[blocks\] expected an array of tables \[\[blocks\]\]"):
        bad.tables("blocks")
