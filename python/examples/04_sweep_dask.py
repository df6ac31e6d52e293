#!/usr/bin/env python3
"""Run a sweep plan's points on a dask.distributed cluster and write the table
``tofkit sweep`` writes, byte for byte.

    PYTHONPATH=build/python /usr/bin/python3 python/examples/04_sweep_dask.py \\
        [PLAN [OUT.csv [WORKERS [CHUNKS]]]]

PLAN defaults to python/examples/plans/issue_sweep.toml, OUT.csv to
sweep.csv. A LocalCluster of WORKERS processes (default 2) stands in for a
real cluster (dask.distributed.Client("scheduler:8786") instead): the points
are split into CHUNKS shards (default 4); each task loads the plan on its
worker and returns its shard's rows, which come back in the shards' order
under the plan's header. Each point is computed from its own settings and
seed, so where and in what order the tasks run does not change a byte.
"""

import pathlib
import sys
import time

from dask.distributed import Client, LocalCluster

import tofkit

HERE = pathlib.Path(__file__).resolve().parent
plan_file = sys.argv[1] if len(sys.argv) > 1 else str(HERE / "plans" / "issue_sweep.toml")
out = sys.argv[2] if len(sys.argv) > 2 else "sweep.csv"
workers = int(sys.argv[3]) if len(sys.argv) > 3 else 2
chunks = int(sys.argv[4]) if len(sys.argv) > 4 else 4


def shard_rows(plan_file, k, n):
    """The rows of shard k of n (runs on a worker)."""
    import tofkit

    plan = tofkit.SweepPlan(plan_file)
    return plan.rows(plan.shard(k, n))


if __name__ == "__main__":
    plan = tofkit.SweepPlan(plan_file)  # checks the plan here, before any task
    start = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        futures = [client.submit(shard_rows, plan_file, k, chunks) for k in range(chunks)]
        rows = [row for shard in client.gather(futures) for row in shard]
    with open(out, "w", encoding="utf-8", newline="\n") as f:
        f.write(plan.header + "\n" + "".join(r + "\n" for r in rows))
    print(f"{plan.points} points on {workers} dask workers in {chunks} shards: "
          f"{time.perf_counter() - start:.1f} s -> {out}")
