"""A newcomer's first hour (issue 31): defaults that give right answers, `plan`
lines that calibrate the device they were printed for, typo help, and the
device link read by a real serial client (pyserial) with a decoder written
from docs/link.md's byte table alone."""

import csv
import math
import os
import pathlib
import re
import shlex
import struct
import subprocess
import sys
import time

import pytest

BINARY = pathlib.Path(os.environ.get(
    "TOFKIT_BINARY", pathlib.Path(__file__).resolve().parents[2] / "build" / "tofkit"))

PLANE_AT_3M = """[sensor]
pose_m = [0, 0, 0]
rpy_deg = [0, 0, 0]

[[surface]]
kind = "plane"
center_m = [3.0, 0, 0]
normal = [-1, 0, 0]
size_m = [4.0, 4.0]
reflectance = 0.5
"""


def tofkit(*args, cwd, check=True, **kw):
    result = subprocess.run([str(BINARY), *map(str, args)], cwd=cwd, capture_output=True,
                            text=True, **kw)
    if check:
        assert result.returncode == 0, f"tofkit {args}: {result.stderr}"
    return result


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# --- scan: calibrated by default, raw on request ------------------------------

SCAN = ["scan", "--scene", "plane.toml", "--pattern", "spherical", "--azimuth=-30:30:1",
        "--elevation=-30:30:1", "--write", "csv,ply"]


def ply_points(path):
    """x, y, z of a binary little-endian PLY's vertices, read from its header."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    assert "format binary_little_endian 1.0" in header
    count = int(next(x for x in header if x.startswith("element vertex")).split()[2])
    sizes = {"float": ("f", 4), "double": ("d", 8), "uchar": ("B", 1), "ushort": ("H", 2),
             "uint": ("I", 4), "int": ("i", 4), "short": ("h", 2), "char": ("b", 1)}
    props = [x.split()[1:] for x in header if x.startswith("property")]
    fmt = "<" + "".join(sizes[t][0] for t, _ in props)
    names = [n for _, n in props]
    step = struct.calcsize(fmt)
    out = []
    for i in range(count):
        values = dict(zip(names, struct.unpack_from(fmt, data, end + i * step)))
        out.append((values["x"], values["y"], values["z"]))
    return out


def test_default_scan_of_a_plane_at_3m_lies_on_the_plane(tmp_path):
    (tmp_path / "plane.toml").write_text(PLANE_AT_3M)
    result = tofkit(*SCAN, "--out", "out/nested/", cwd=tmp_path)  # the directory is made
    assert "factory calibration" in result.stderr
    points = ply_points(tmp_path / "out" / "nested" / "points.ply")
    assert len(points) == 61 * 61
    worst = max(abs(x - 3.0) for x, _, _ in points)  # the plane x = 3 m
    print(f"plane at 3 m: {len(points)} points, max point-to-plane distance {worst * 1e3:.2f} mm")
    assert worst < 0.005


def test_raw_scan_gives_the_raw_ranges(tmp_path):
    (tmp_path / "plane.toml").write_text(PLANE_AT_3M)
    raw = tofkit(*SCAN, "--raw", "--out", "raw", cwd=tmp_path)
    assert "raw ranges" in raw.stderr
    calibrated = tofkit(*SCAN, "--out", "cal", cwd=tmp_path)
    raw_rows, cal_rows = rows(tmp_path / "raw" / "scan.csv"), rows(tmp_path / "cal" / "scan.csv")
    # --raw: no corrected columns; the raw columns are the same beams' as
    # the calibrated scan's (the correction does not touch the measurement).
    assert "distance_m" not in raw_rows[0] and "distance_m" in cal_rows[0]
    for r, c in zip(raw_rows, cal_rows, strict=True):
        for column in ("tof_ns", "distance_raw_m", "pulse_width_ns", "amplitude", "flags"):
            assert r[column] == c[column]
    # The raw ranges carry the device's fixed delays (~0.25 m on the paper device)...
    errors = [float(r["distance_raw_m"]) - float(r["distance_true_m"]) for r in raw_rows]
    assert min(errors) > 0.15
    # ... and the cloud is where the raw ranges put it: range along the beam.
    points = ply_points(tmp_path / "raw" / "points.ply")
    for (x, y, z), r in zip(points, raw_rows):
        d = float(r["distance_raw_m"])
        assert abs(x - d * float(r["dir_x"])) < 1e-5


def test_spherical_scan_with_default_shots_is_not_refused(tmp_path):
    (tmp_path / "plane.toml").write_text(PLANE_AT_3M)
    result = tofkit("scan", "--scene", "plane.toml", "--pattern", "spherical",
                    "--azimuth", "0", "--elevation=-10:10:1", "--raw", "--write", "csv",
                    "--out", "o", cwd=tmp_path)
    shots = int(re.search(r"(\d+) shots", result.stderr).group(1))
    assert 1 <= shots < 1000  # fewer than the config's 1000: what fits 0.278 ms
    refused = tofkit("scan", "--scene", "plane.toml", "--pattern", "spherical",
                     "--azimuth", "0", "--elevation=-10:10:1", "--shots", "1000", "--out", "o2",
                     cwd=tmp_path, check=False)
    assert refused.returncode == 1
    assert "--shots" in refused.stderr and "--rate" in refused.stderr


def test_measure_out_dash_is_stdout(tmp_path):
    result = tofkit("measure", "--distance", "1,2", "--reflectance", "0.5", "--out", "-",
                    cwd=tmp_path)
    assert result.stdout.startswith("distance_true_m,")
    assert len(result.stdout.splitlines()) == 3
    assert not (tmp_path / "-").exists()


# --- plan carries the device ----------------------------------------------------

DEVICE = ["--set", "laser.pulse_width_ns=3", "--set", "receiver.bandwidth_mhz=100"]


def test_plan_lines_calibrate_the_device_they_were_printed_for(tmp_path):
    printed = tofkit(*DEVICE, "plan", "--range-max", "6", cwd=tmp_path).stdout
    lines = [x for x in printed.splitlines() if x.startswith("tofkit ")]
    assert lines[-4].split()[len(DEVICE) + 1] == "fit"
    assert "--seed 2" in lines[-3]
    (tmp_path / "printed").mkdir()
    for line in lines:  # as printed, `tofkit` being the binary
        args = shlex.split(line)[1:]
        tofkit(*args, cwd=tmp_path / "printed")
    # The same protocol typed by hand: the plan printed for the default
    # device's options, with the device's options typed on every line.
    (tmp_path / "hand").mkdir()
    plain = tofkit(*DEVICE, "plan", "--range-max", "6", cwd=tmp_path).stdout
    measured = []
    for line in plain.splitlines():
        if not line.startswith("tofkit "):
            continue
        words = shlex.split(line)[1 + len(DEVICE):]  # the command and its own options
        if words[0] == "measure" and "--seed" not in words:
            out = words[words.index("--out") + 1]
            measured.append(out)
            tofkit(*DEVICE, "measure", *words[1:], cwd=tmp_path / "hand")
    inputs = [a for name in measured for a in ("--in", name)]
    tofkit(*DEVICE, "fit", *inputs, "--chain", "offset,grayvalue,temperature", "--out",
           "model.json", cwd=tmp_path / "hand")
    printed_model = (tmp_path / "printed" / "model.json").read_text()
    assert printed_model.replace("printed", "") == \
        (tmp_path / "hand" / "model.json").read_text().replace("hand", "")
    # Pasted without the device options (the old lines), the fit calibrates
    # another device: a different model.
    (tmp_path / "other").mkdir()
    for name, line in zip(measured, [x for x in plain.splitlines() if " measure " in x]):
        words = shlex.split(line)[1 + len(DEVICE):]
        tofkit(*words, cwd=tmp_path / "other")
    tofkit("fit", *inputs, "--chain", "offset,grayvalue,temperature", "--out", "model.json",
           cwd=tmp_path / "other")
    assert (tmp_path / "other" / "model.json").read_text() != \
        (tmp_path / "hand" / "model.json").read_text()
    # The test line on another seed: corrected within a few mm.
    tested = rows(tmp_path / "printed" / "test_corrected.csv")
    errors = [abs(float(r["distance_m"]) - float(r["distance_true_m"])) for r in tested
              if r["distance_m"] and int(r["flags"]) == 0]
    assert errors and max(errors) < 0.02


# --- typo help ----------------------------------------------------------------

def test_typo_in_a_command_suggests_the_command(tmp_path):
    result = tofkit("mesure", "--distance", "1", cwd=tmp_path, check=False)
    assert result.returncode == 2
    assert "did you mean 'measure'" in result.stderr


def test_typo_in_an_option_suggests_the_option(tmp_path):
    result = tofkit("measure", "--distnce", "1", "--reflectance", "0.5", "--out", "a.csv",
                    cwd=tmp_path, check=False)
    assert result.returncode == 2
    assert "--distnce" in result.stderr and "did you mean '--distance'" in result.stderr
