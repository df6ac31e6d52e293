"""The README's example outputs are what the commands print today.

Each fenced block of the README that shows a command's output is run again
and compared line by line, apart from wall-clock times and output paths:
three of them had gone stale when the twin's physics changed in an earlier
change, unnoticed, until a person re-ran them.
"""

import csv
import pathlib
import re
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
BLOCKS_SCENE = ROOT / "examples" / "scenes" / "blocks.toml"


def fenced_blocks():
    """The README's fenced blocks, each as its list of lines."""
    blocks, current = [], None
    for line in README.read_text().splitlines():
        if line.startswith("```"):
            if current is None:
                current = []
            else:
                blocks.append(current)
                current = None
        elif current is not None:
            current.append(line)
    return blocks


def block_with(text):
    """The one fenced block holding `text`."""
    found = [b for b in fenced_blocks() if any(text in line for line in b)]
    assert len(found) == 1, f"{len(found)} README blocks hold {text!r}"
    return found[0]


def lines_after(block, text):
    """The lines of `block` after the line holding `text`, up to the next `$ ` line."""
    start = next(i for i, line in enumerate(block) if text in line) + 1
    out = []
    for line in block[start:]:
        if line.startswith("$ "):
            break
        out.append(line)
    return out


def timeless(line):
    """A line with its wall-clock figures and output path blanked."""
    line = re.sub(r"\d+(\.\d+)? s\b", "T s", line)
    line = re.sub(r"at most \d+(\.\d+)? ms late", "at most T ms late", line)
    return re.sub(r"-> \S+$", "-> PATH", line)


def csv_rows(lines):
    """The CSV lines (header and rows) of a block or an output."""
    return [line for line in lines if re.match(r"^(\d|sequence,|row,)", line)]


def test_demo_output(cli, tmp_path):
    expected = block_with("tofkit demo: the paper's Section 5 on the virtual rangefinder")
    printed = cli("demo", "--out", "demo-out", cwd=tmp_path).stdout.splitlines()
    assert [timeless(x) for x in printed] == [timeless(x) for x in expected]


@pytest.mark.parametrize("command", [
    "plan --range-max 8 --reflectance-min 0.05",
    "plan --range-min 0.7 --range-max 7.4 --reflectance-min 0.06 --reflectance-max 0.85 "
    "--single-distance",
])
def test_plan_output(cli, command):
    expected = lines_after(block_with(f"$ tofkit {command}"), f"$ tofkit {command}")
    assert cli(*command.split()).stdout.splitlines() == expected


def test_error_examples(cli, tmp_path):
    block = block_with("$ tofkit correct --model model.json --in bad.csv --out out.csv")
    bandwidth = cli("--set", "receiver.bandwidth_mhz=1", "measure", "--distance", "1",
                    "--reflectance", "0.5", "--out", "a.csv", check=False, cwd=tmp_path)
    assert bandwidth.returncode == 1
    assert bandwidth.stderr.splitlines() == lines_after(
        block, "$ tofkit --set receiver.bandwidth_mhz=1 measure")
    cli("demo", "--out", "demo", cwd=tmp_path)
    cli("measure", "--distance", "1:3:1", "--reflectance", "0.5", "--out", "raw.csv", cwd=tmp_path)
    lines = (tmp_path / "raw.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[4] = "1e999"  # line 4, column 5 (tof_ns), at character 12 as the README's
    lines[3] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    bad = cli("correct", "--model", "demo/model.json", "--in", "bad.csv", "--out", "out.csv",
              check=False, cwd=tmp_path)
    assert bad.returncode == 1
    assert bad.stderr.splitlines() == lines_after(
        block, "$ tofkit correct --model model.json --in bad.csv --out out.csv")
    same = cli("correct", "--model", "demo/model.json", "--in", "raw.csv", "--out", "raw.csv",
               check=False, cwd=tmp_path)
    assert same.returncode == 1
    assert same.stderr.splitlines() == lines_after(
        block, "$ tofkit correct --model model.json --in raw.csv --out raw.csv")


def emulate_into_stream(binary, emulate_args, stream_args, cwd):
    """`tofkit emulate ... --out - | tofkit stream ... --in - --out -`: (emulate's
    stderr, stream's stdout, stream's stderr)."""
    emulate = subprocess.Popen([binary, "emulate", *map(str, emulate_args), "--out", "-"],
                               cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stream = subprocess.run([binary, "stream", *map(str, stream_args), "--in", "-", "--out", "-"],
                            cwd=cwd, stdin=emulate.stdout, capture_output=True, text=True)
    emulate.stdout.close()
    emulate_err = emulate.stderr.read().decode()
    assert emulate.wait() == 0, emulate_err
    assert stream.returncode == 0, stream.stderr
    return emulate_err, stream.stdout, stream.stderr


def test_emulate_session(cli, cli_binary, tmp_path):
    # The README's session goes through a pty; a pipe carries the same frames.
    block = block_with("$ tofkit stream --format native --in /dev/pts/0 --model model.json")
    cli("demo", "--out", "demo", cwd=tmp_path)
    _, rows, _ = emulate_into_stream(
        cli_binary, ["--format", "native", "--rate", "1000", "--distance", "2,6", "--reflectance",
                     "0.1", "--count", "2", "--shots", "200", "--seed", "7"],
        ["--format", "native", "--model", "demo/model.json"], tmp_path)
    assert csv_rows(rows.splitlines()) == csv_rows(block)


def test_emulate_scene_and_scan(cli, cli_binary, tmp_path):
    block = block_with("$ tofkit emulate --format native --rate 1000 --scene blocks.toml")
    for name in ("blocks.toml", "roof.obj"):
        (tmp_path / name).write_text((BLOCKS_SCENE.parent / name).read_text())
    pattern = ["--pattern", "spherical", "--azimuth=-10:10:10", "--elevation", "0,10",
               "--shots", "200", "--seed", "7"]
    emulate_err, rows, stream_err = emulate_into_stream(
        cli_binary, ["--format", "native", "--rate", "1000", "--scene", "blocks.toml", *pattern],
        ["--format", "native"], tmp_path)
    printed = rows.splitlines() + emulate_err.splitlines() + stream_err.splitlines()
    expected = lines_after(block, "tofkit stream --format native --in - --out -")
    assert [timeless(x) for x in printed] == [timeless(x) for x in expected]

    (tmp_path / "scan").mkdir()
    cli("scan", "--scene", "blocks.toml", *pattern, "--write", "csv", "--out", "scan/",
        cwd=tmp_path)
    header, *rows = lines_after(block, "--shots 200 --seed 7 --write csv --out scan/")
    with open(tmp_path / "scan" / "scan.csv", newline="") as f:
        scanned = [",".join(row[c] for c in header.split(",")) for row in csv.DictReader(f)]
    assert scanned == rows


def test_python_scan_example(tmp_path):
    pytest.importorskip("matplotlib")
    import os
    import sys

    block = block_with("<tofkit.ScanResult spherical 301 x 301")
    env = dict(os.environ, MPLBACKEND="Agg")
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    result = subprocess.run(
        [sys.executable, ROOT / "python" / "examples" / "03_scan_blocks.py", "blocks_range.png"],
        cwd=tmp_path, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert [timeless(x) for x in result.stdout.splitlines()] == [timeless(x) for x in block]
