"""Scanning: a scene file scanned by a pattern through the virtual
rangefinder, as ``tofkit scan``, with NumPy images and points instead of files."""

import os

from . import _tofkit
from .device import _config, _float, _int, _seed

BEAM_DTYPE = _tofkit.BEAM_DTYPE
"""The per-beam table's fields: scan.csv's columns (row, column, time_s,
origin and direction in the world frame, distance_true_m, reflectance,
angle_deg, the raw device columns, distance_m, sigma_m, correction_flags)
plus position_m (line scans) and surfaces (2+: a mixed pixel)."""

POINT_COLUMNS = _tofkit.POINT_COLUMNS
"""The columns of ScanResult.points, the fields of the CLI's PLY/PCD files:
x, y, z (world frame, m), intensity (V), range (m), sigma (m), row, column,
time_s, flags (the raw measurement's)."""


class ScanResult:
    """What ``tofkit scan`` writes, as arrays.

    range, intensity, sigma, truth: 2-D float32 images (rows x columns; row 0
    the top, column 0 the left; NaN where no beam had an echo), as the CLI's
    range.npy, intensity.npy and sigma.npy (sigma is NaN without a model).
    points: (N, 10) float64, one row per beam with an echo, columns POINT_COLUMNS.
    beams: every beam in time order, a structured array of BEAM_DTYPE (its
    raw columns can go straight to Model.apply).
    """

    def __init__(self, fields):
        self.range = fields["range"]
        self.intensity = fields["intensity"]
        self.sigma = fields["sigma"]
        self.truth = fields["truth"]
        self.points = fields["points"]
        self.beams = fields["beams"]
        self.pattern = fields["pattern"]
        self.shape = (fields["rows"], fields["columns"])
        self.shots = fields["shots"]
        self.has_model = fields["has_model"]
        self.sensor_position_m = tuple(fields["sensor_position_m"])
        self.sensor_rpy_deg = tuple(fields["sensor_rpy_deg"])

    def point(self, column):
        """One column of ``points`` by name (a view)."""
        return self.points[:, POINT_COLUMNS.index(column)]

    def __repr__(self):
        return (f"<tofkit.ScanResult {self.pattern} {self.shape[0]} x {self.shape[1]}, "
                f"{len(self.beams)} beams, {len(self.points)} points"
                f"{', corrected' if self.has_model else ''}>")


def scan(scene, pattern, *, y=None, z=None, azimuth=None, elevation=None, samples=1,
         speed_m_per_s=0.05, turnaround_s=0.5, rate_hz=10.0, revolutions=1,
         azimuth_step_deg=0.2, model=None, mode="analytic", shots=None, seed=1,
         ambient_c=None, config=None, shard=None):
    """Scan a scene file (TOML) with a pattern, as ``tofkit scan``.

    pattern: "raster" | "line" (y, z: stage positions, m) | "mirror" |
    "spinning" (elevation, degrees) | "spherical" (azimuth, elevation, degrees).
    Each of y, z, azimuth, elevation is a number, a list/array, or the CLI's
    text ("a,b,c" or "start:stop:step", expanded exactly as the CLI does).
    The other arguments are the CLI's options with its defaults: samples,
    speed_m_per_s (--speed), turnaround_s, rate_hz (--rate), revolutions,
    azimuth_step_deg, mode ("analytic" or "waveform"), shots (None: the
    config's), seed, ambient_c (--ambient, C; None: the CLI's default); model: a Model (or a model file's
    path) applied to every beam, adding corrected range and sigma; config: a
    DeviceConfig (None: the default one). The same arguments and seed give the
    same numbers as ``tofkit scan`` on any thread count.

    shard: (k, n) scans only beams [k N / n, (k + 1) N / n) of the N, as
    ``tofkit scan --shard k/n``: the same values as those beams have in the
    whole scan (each beam has its own random stream), so shards run anywhere
    (a cluster's workers) and their beams and points concatenate, in k's
    order, into the whole scan's; the images hold the shard's pixels only
    (NaN elsewhere).

    Returns a ScanResult. Raises FileNotFoundError for a missing scene file
    and ValueError (with the CLI's message) for a bad scene, key or value.
    The GIL is released while scanning.
    """
    from .model import Model

    if isinstance(model, (str, os.PathLike)):
        model = Model.load(model)
    if model is not None and not isinstance(model, Model):
        raise TypeError(f"model: expected a tofkit.Model or a path, got {type(model).__name__}")
    args = _tofkit._ScanArgs()
    args.pattern = str(pattern)
    args.y, args.z, args.azimuth, args.elevation = y, z, azimuth, elevation
    args.samples = _int(samples, "samples")
    args.revolutions = _int(revolutions, "revolutions")
    # (None: the config's; else as tofkit scan --shots and measure())
    args.shots = 0 if shots is None else _int(shots, "shots", 1, 10_000_000)
    args.speed_m_per_s = _float(speed_m_per_s, "speed_m_per_s")
    args.turnaround_s = _float(turnaround_s, "turnaround_s")
    args.rate_hz = _float(rate_hz, "rate_hz")
    args.azimuth_step_deg = _float(azimuth_step_deg, "azimuth_step_deg")
    if ambient_c is not None:
        args.ambient_c = _float(ambient_c, "ambient_c")
    args.seed = _seed(seed)
    args.mode = str(mode)
    if shard is not None:
        k, n = shard
        args.shard_index = _int(k, "shard k", 0, 1_000_000)
        args.shard_count = _int(n, "shard n", 1, 1_000_000)
    return ScanResult(_tofkit._scan(_config(config), os.fspath(scene), args,
                                    None if model is None else model._model))
