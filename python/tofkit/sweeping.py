"""Sweeps: a plan (TOML) of parameter axes and measurements, one table row per
point, as ``tofkit sweep`` (the same C++ code, so the same bytes)."""

import os

from . import _tofkit
from .device import _int

__all__ = ["SweepPlan", "sweep"]


class SweepPlan:
    """A loaded sweep plan: ``points`` (how many), ``header`` (the table's
    first line), ``axes`` ([(key, values)]), and ``rows(points)``, the table
    rows of those point indices (computed in parallel, GIL released). A plan
    is cheap to rebuild from its file: a cluster's workers load their own."""

    def __init__(self, plan, *, preset="", config=None, sets=()):
        self._base = (str(preset), None if config is None else os.fspath(config),
                      [str(s) for s in sets])
        self._plan = _tofkit._sweep_plan(os.fspath(plan), *self._base)
        self.file = os.fspath(plan)

    @property
    def points(self):
        return self._plan.points

    @property
    def header(self):
        return self._plan.header

    @property
    def axes(self):
        return self._plan.axes

    def shard(self, k, n):
        """Point indices of shard k of n: [k P / n, (k + 1) P / n), as --shard k/n."""
        k, n = _int(k, "shard k", 0, 1_000_000), _int(n, "shard n", 1, 1_000_000)
        if k >= n:
            raise ValueError("shard: (k, n) needs k = 0 .. n - 1")
        p = self.points
        at = lambda j: p // n * j + p % n * j // n  # noqa: E731
        return range(at(k), at(k + 1))

    def rows(self, points):
        return _tofkit._sweep_rows(self._plan, *self._base, [int(p) for p in points])


def sweep(plan, *, out=None, shard=None, preset="", config=None, sets=()):
    """Run a sweep plan (a TOML file, as ``tofkit sweep --plan``) and return
    its table as text (header, then a row per point, axes first). ``shard``
    (k, n) runs only the points of ``tofkit sweep --shard k/n``; the shards'
    rows, concatenated in k's order under one header, are the whole table.
    ``out``: also write the table there (a file path). ``preset``,
    ``config`` (a config file) and ``sets`` (["section.key=value", ...]) are
    the CLI's --preset, --config and --set."""
    p = SweepPlan(plan, preset=preset, config=config, sets=sets)
    points = range(p.points) if shard is None else p.shard(*shard)
    table = p.header + "\n" + "".join(row + "\n" for row in p.rows(points))
    if out is not None:
        with open(out, "w", encoding="utf-8", newline="\n") as f:
            f.write(table)
    return table
