"""DeviceConfig: presets, TOML files and overrides with the CLI's validation."""

import pytest

import tofkit
from conftest import cli_error


def test_dump_matches_the_cli_and_loads_back(cli, tmp_path):
    config = tofkit.DeviceConfig("accurange", set=["laser.pulse_width_ns=3.5"])
    printed = cli("--preset", "accurange", "--set", "laser.pulse_width_ns=3.5", "config",
                  "--dump").stdout
    assert config.dump() == printed
    path = tmp_path / "dev.toml"
    path.write_text(config.dump())
    again = tofkit.DeviceConfig(file=path)
    assert again.dump() == config.dump()
    assert again.name == "accurange"
    assert again["laser.pulse_width_ns"] == 3.5
    assert again.to_dict() == config.to_dict()


def test_override_types():
    config = tofkit.DeviceConfig(set={"measurement.shots": 250, "receiver.bandwidth_mhz": 120.5,
                                      "receiver.bias_temperature_compensated": False})
    assert config["measurement.shots"] == 250
    assert config["receiver.bandwidth_mhz"] == 120.5
    assert config["receiver.bias_temperature_compensated"] is False
    assert "paper" in tofkit.DeviceConfig.presets()
    assert isinstance(config, tofkit.DeviceConfig)
    assert tofkit.DeviceConfig(set="measurement.shots=3")["measurement.shots"] == 3


def errors_match(cli, args, make):
    expected = cli_error(cli(*args, "config", "--dump", check=False))
    with pytest.raises(ValueError) as error:
        make()
    assert str(error.value) == expected
    return error


def test_unknown_key(cli):
    errors_match(cli, ["--set", "receiver.bandwith_mhz=1"],
                 lambda: tofkit.DeviceConfig(set={"receiver.bandwith_mhz": 1}))


def test_value_out_of_range(cli):
    errors_match(cli, ["--set", "receiver.bandwidth_mhz=0"],
                 lambda: tofkit.DeviceConfig(set=["receiver.bandwidth_mhz=0"]))


def test_wrong_type(cli):
    errors_match(cli, ["--set", "measurement.shots=2.5"],
                 lambda: tofkit.DeviceConfig(set=["measurement.shots=2.5"]))


def test_unknown_preset(cli):
    errors_match(cli, ["--preset", "nope"], lambda: tofkit.DeviceConfig("nope"))


def test_bad_file(cli, tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[receiver]\nbandwidth_mhz = \"wide\"\n[lasr]\n")
    error = errors_match(cli, ["--config", path], lambda: tofkit.DeviceConfig(file=path))
    assert f"{path}:2" in str(error.value)


def test_missing_file_is_file_not_found(cli, tmp_path):
    path = tmp_path / "missing.toml"
    expected = cli_error(cli("--config", path, "config", "--dump", check=False))
    with pytest.raises(FileNotFoundError) as error:
        tofkit.DeviceConfig(file=path)
    assert str(error.value) == expected
