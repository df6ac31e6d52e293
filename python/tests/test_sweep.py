"""tofkit.sweep and scan shards: the CLI's bytes, from Python."""

import pathlib

import numpy as np
import pytest

import tofkit

ROOT = pathlib.Path(__file__).resolve().parents[2]
PLAN = ROOT / "python" / "examples" / "plans" / "issue_sweep.toml"
BLOCKS = ROOT / "examples" / "scenes" / "blocks.toml"


def test_sweep_table_is_the_cli_table_and_shards_concatenate(cli, tmp_path):
    cli("sweep", "--plan", PLAN, "--out", tmp_path / "cli")
    expected = (tmp_path / "cli" / "sweep.csv").read_text()
    assert tofkit.sweep(PLAN) == expected
    plan = tofkit.SweepPlan(PLAN)
    assert plan.points == 24
    assert plan.header == expected.splitlines()[0]
    parts = [tofkit.sweep(PLAN, shard=(k, 3)) for k in range(3)]
    joined = parts[0] + "".join(p.split("\n", 1)[1] for p in parts[1:])
    assert joined == expected
    # The CLI's shards hold the same rows.
    cli("sweep", "--plan", PLAN, "--shard", "1/3", "--out", tmp_path / "s1")
    assert (tmp_path / "s1" / "sweep.csv").read_text() == parts[1]


def test_bad_plan_names_its_line(tmp_path):
    bad = tmp_path / "plan.toml"
    bad.write_text('[axes]\n"laser.pulse_widht_ns" = [1.0]\n[measure]\ndistance_m = 1\n')
    with pytest.raises(ValueError, match=r"plan.toml:2: axis 'laser.pulse_widht_ns'"):
        tofkit.sweep(bad)
    with pytest.raises(ValueError, match="shard"):
        tofkit.sweep(PLAN, shard=(3, 3))


def test_scan_shards_are_the_whole_scans_beams():
    kw = dict(azimuth="-20:20:1", elevation="-10:10:1", shots=5, seed=3)
    whole = tofkit.scan(BLOCKS, "spherical", **kw)
    parts = [tofkit.scan(BLOCKS, "spherical", shard=(k, 3), **kw) for k in range(3)]
    assert sum(len(p.beams) for p in parts) == len(whole.beams)
    beams = np.concatenate([p.beams for p in parts])
    for name in beams.dtype.names:
        np.testing.assert_array_equal(beams[name], whole.beams[name], err_msg=name)
    np.testing.assert_array_equal(np.concatenate([p.points for p in parts]), whole.points)
    # Each pixel (one beam each) is set in exactly one shard's image.
    stacked = np.stack([p.range for p in parts])
    assert (np.isfinite(stacked).sum(axis=0) <= 1).all()
    combined = np.where(np.isfinite(stacked), stacked, -np.inf).max(axis=0)
    np.testing.assert_array_equal(combined, np.where(np.isfinite(whole.range), whole.range, -np.inf))
