"""tofkit.scan against `tofkit scan`: the same images (its .npy files), the
same points (its PLY file), the same errors; the GIL released while scanning."""

import pathlib

import numpy as np
import pytest

import tofkit
from conftest import cli_error, pauses_of_another_thread

SCENES = pathlib.Path(__file__).resolve().parents[2] / "examples" / "scenes"
BLOCKS = SCENES / "blocks.toml"
GRID = "-15:15:1.5"  # 21 x 21 beams over the blocks scene


def read_ply(path):
    """The CLI's binary PLY as a structured array (its header names the fields)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    types = {"double": "<f8", "float": "<f4", "int": "<i4"}
    fields = [(line.split()[2], types[line.split()[1]])
              for line in data[:end].decode().splitlines() if line.startswith("property")]
    return np.frombuffer(data[end:], dtype=np.dtype(fields))


def cli_scan(cli, out, *args):
    out.mkdir()
    # Python's scan() without a model is raw: the CLI's default corrects (factory calibration).
    raw = [] if "--model" in args else ["--raw"]
    cli("scan", "--scene", BLOCKS, *args, *raw, "--write", "npy,ply", "--out", out)
    return {name: np.load(out / f"{name}.npy") for name in ("range", "intensity", "sigma")
            if (out / f"{name}.npy").exists()}, read_ply(out / "points.ply")


def assert_points_equal(points, ply):
    """ScanResult.points against the PLY's fields, column by column, bit for bit."""
    assert points.shape == (len(ply), len(tofkit.POINT_COLUMNS))
    ply_names = {"time_s": "time"}
    for k, name in enumerate(tofkit.POINT_COLUMNS):
        np.testing.assert_array_equal(points[:, k], ply[ply_names.get(name, name)].astype(np.float64),
                                      err_msg=name)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A chain fitted on the default device, and its file for the CLI."""
    records = tofkit.measure(np.arange(0.5, 4.01, 0.5), [0.05, 0.3, 0.9], count=2, shots=50,
                             seed=2)
    model = tofkit.fit_chain(records, steps="offset,grayvalue")
    path = tmp_path_factory.mktemp("model") / "model.json"
    model.save(path)
    return model, path


def test_spherical_scan_equals_tofkit_scan(cli, tmp_path):
    images, ply = cli_scan(cli, tmp_path / "cli", "--pattern", "spherical", "--azimuth", GRID,
                           "--elevation", GRID, "--shots", "10", "--seed", "7")
    result = tofkit.scan(BLOCKS, "spherical", azimuth=GRID, elevation=GRID, shots=10, seed=7)
    assert result.shape == (21, 21) and result.range.shape == (21, 21)
    assert result.range.dtype == np.float32
    np.testing.assert_array_equal(result.range, images["range"])
    np.testing.assert_array_equal(result.intensity, images["intensity"])
    assert "sigma" not in images and np.isnan(result.sigma).all()  # no model
    assert_points_equal(result.points, ply)
    # The scene has depth: the images are not constant, and the points lie at the ranges.
    assert np.nanstd(result.range) > 0.05
    xyz = result.points[:, :3]
    np.testing.assert_allclose(np.linalg.norm(xyz, axis=1), result.point("range"), rtol=1e-6)
    assert len(result.beams) == 21 * 21
    # Another seed draws other noise.
    other = tofkit.scan(BLOCKS, "spherical", azimuth=GRID, elevation=GRID, shots=10, seed=8)
    assert not np.array_equal(other.range, result.range, equal_nan=True)


def test_raster_with_a_model_equals_tofkit_scan(cli, tmp_path, model):
    model, path = model
    y = [-0.3, -0.1, 0.1, 0.3]
    z = [-0.2, 0.0, 0.2]
    images, ply = cli_scan(cli, tmp_path / "cli", "--pattern", "raster", "--y", "-0.3,-0.1,0.1,0.3",
                           "--z", "-0.2,0,0.2", "--samples", "2", "--model", path, "--ambient", "30")
    result = tofkit.scan(BLOCKS, "raster", y=np.array(y), z=z, samples=2, model=model, ambient_c=30)
    assert result.has_model and result.shape == (3, 4)
    for name in ("range", "intensity", "sigma"):
        np.testing.assert_array_equal(getattr(result, name), images[name], err_msg=name)
    assert np.isfinite(result.sigma).any()
    assert_points_equal(result.points, ply)
    # The per-beam table holds the raw columns: Model.apply on it gives the beams' ranges.
    distance, sigma, flags = model.apply(result.beams)
    np.testing.assert_array_equal(distance, result.beams["distance_m"])
    np.testing.assert_array_equal(flags, result.beams["correction_flags"])
    # A model file's path works as well.
    again = tofkit.scan(BLOCKS, "raster", y=y, z=z, samples=2, model=path, ambient_c=30)
    np.testing.assert_array_equal(again.sigma, result.sigma)


@pytest.mark.parametrize("cli_args, kwargs", [
    (["--pattern", "line", "--y", "-0.4:0.4:0.05", "--z", "-0.2,0.1", "--speed", "0.2",
      "--turnaround", "0.3"],
     dict(pattern="line", y="-0.4:0.4:0.05", z=[-0.2, 0.1], speed_m_per_s=0.2,
          turnaround_s=0.3)),
    (["--pattern", "mirror", "--elevation", "-20:10:2", "--revolutions", "4", "--rate", "5",
      "--speed", "0.1"],
     dict(pattern="mirror", elevation="-20:10:2", revolutions=4, rate_hz=5, speed_m_per_s=0.1)),
    (["--pattern", "spinning", "--elevation", "-10,-5,0,5", "--azimuth-step", "4",
      "--rate", "20", "--mode", "waveform", "--shots", "3"],
     dict(pattern="spinning", elevation=[-10, -5, 0, 5], azimuth_step_deg=4, rate_hz=20,
          mode="waveform", shots=3)),
], ids=["line", "mirror", "spinning-waveform"])
def test_every_pattern_equals_tofkit_scan(cli, tmp_path, cli_args, kwargs):
    images, ply = cli_scan(cli, tmp_path / "cli", *cli_args, "--seed", "4")
    result = tofkit.scan(BLOCKS, seed=4, **kwargs)
    for name in ("range", "intensity"):
        np.testing.assert_array_equal(getattr(result, name), images[name], err_msg=name)
    assert np.isfinite(result.range).any()
    assert_points_equal(result.points, ply)


def test_errors_carry_the_cli_message(cli, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    missing = tmp_path / "missing.toml"
    expected = cli_error(cli("scan", "--scene", missing, "--pattern", "spherical", "--azimuth",
                             "0", "--elevation", "0", "--out", out, check=False))
    with pytest.raises(FileNotFoundError) as error:
        tofkit.scan(missing, "spherical", azimuth=0, elevation=0)
    assert str(error.value) == expected

    bad = tmp_path / "bad.toml"
    (tmp_path / "roof.obj").write_bytes((SCENES / "roof.obj").read_bytes())
    bad.write_text(BLOCKS.read_text().replace("radius_m = 0.06\nreflectance = 0.8",
                                              "radius_m = 0.06\nreflectivity = 0.8"))
    expected = cli_error(cli("scan", "--scene", bad, "--pattern", "spherical", "--azimuth", "0",
                             "--elevation", "0", "--out", out, check=False))
    assert "reflectivity" in expected
    with pytest.raises(ValueError) as error:
        tofkit.scan(bad, "spherical", azimuth=0, elevation=0)
    assert str(error.value) == expected

    with pytest.raises(ValueError, match="pattern spherical needs azimuth"):
        tofkit.scan(BLOCKS, "spherical", elevation=0)
    with pytest.raises(ValueError, match="elevation: 'x' is not a number"):
        tofkit.scan(BLOCKS, "spherical", azimuth=0, elevation="x")
    with pytest.raises(ValueError, match="is not raster, line"):
        tofkit.scan(BLOCKS, "zigzag", y=0, z=0)
    with pytest.raises(ValueError, match=r"samples: 0 is not in \[1, 100000\]"):
        tofkit.scan(BLOCKS, "raster", y=0, z=0, samples=0)
    with pytest.raises(ValueError, match="mode"):
        tofkit.scan(BLOCKS, "raster", y=0, z=0, mode="exact")
    with pytest.raises(ValueError, match="revolutions: expected an integer, got 'two'"):
        tofkit.scan(BLOCKS, "mirror", elevation=0, revolutions="two")
    # Beyond the C++ field's type: refused by name, not with pybind's TypeError.
    with pytest.raises(ValueError, match=r"revolutions: 1180591620717411303424 is outside"):
        tofkit.scan(BLOCKS, "mirror", elevation=0, revolutions=2**70)
    with pytest.raises(ValueError, match=r"seed: 18446744073709551616 is outside \[0, "):
        tofkit.scan(BLOCKS, "mirror", elevation=0, seed=2**64)
    with pytest.raises(ValueError, match=r"seed: -1 is outside \[0, "):
        tofkit.scan(BLOCKS, "mirror", elevation=0, seed=-1)
    with pytest.raises(ValueError, match="speed_m_per_s: expected a number, got 'fast'"):
        tofkit.scan(BLOCKS, "line", y="0:0.1:0.05", z=0, speed_m_per_s="fast")
    with pytest.raises(ValueError, match=r"shots: 0 is outside \[1, 10000000\]"):
        tofkit.scan(BLOCKS, "mirror", elevation=0, shots=0)
    with pytest.raises(ValueError, match="speed_m_per_s: expected a number, got '0.05'"):
        tofkit.scan(BLOCKS, "line", y="0:0.1:0.05", z=0, speed_m_per_s="0.05")
    with pytest.raises(ValueError, match="samples: expected an integer, got '3'"):
        tofkit.scan(BLOCKS, "raster", y=0, z=0, samples="3")
    with pytest.raises(ValueError, match="rate_hz: expected a number, got None"):
        tofkit.scan(BLOCKS, "mirror", elevation=0, rate_hz=None)
    with pytest.raises(TypeError):
        tofkit.scan(BLOCKS, "raster", y=0, z=0, model=3)


def test_the_gil_is_released_while_scanning():
    """Another Python thread keeps running during a scan."""
    grid = "-15:15:0.25"  # 121 x 121 beams

    def work():
        return tofkit.scan(BLOCKS, "spherical", azimuth=grid, elevation=grid, shots=10)

    work()  # (first call: the scene's acceleration structure)
    gaps, ran = pauses_of_another_thread(work)
    gaps = np.array(gaps)
    print(f"\nscan {ran * 1e3:.0f} ms; longest pause of the other thread "
          f"{gaps.max() * 1e3:.1f} ms over {len(gaps)} ticks")
    assert len(gaps) > 100
    assert gaps.max() < 0.5 * ran


def test_example_03_runs(tmp_path):
    """python/examples/03_scan_blocks.py on a coarse grid, without a display."""
    import os
    import subprocess
    import sys

    pytest.importorskip("matplotlib")
    script = pathlib.Path(__file__).resolve().parents[1] / "examples" / "03_scan_blocks.py"
    out = tmp_path / "blocks.png"
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run([sys.executable, str(script), str(out), "3"], env=env,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "11 x 11" in result.stdout and f"wrote {out}" in result.stdout
    assert out.read_bytes().startswith(b"\x89PNG")
