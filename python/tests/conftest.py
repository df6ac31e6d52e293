"""Shared fixtures: the tofkit CLI (the oracle the package must agree with)."""

import os
import pathlib
import subprocess

import pytest


def _cli_path():
    given = os.environ.get("TOFKIT_BINARY")
    if given:
        return pathlib.Path(given)
    return pathlib.Path(__file__).resolve().parents[2] / "build" / "tofkit"


@pytest.fixture(scope="session")
def cli_binary():
    """The tofkit CLI's path (the test is skipped if it is not built)."""
    path = _cli_path()
    if not path.exists():
        pytest.skip(f"the tofkit CLI is not built ({path})")
    return path


@pytest.fixture(scope="session")
def cli(cli_binary):
    """Runs `tofkit ARGS...`; returns the CompletedProcess (text mode). With
    cwd=, in that directory."""

    def run(*args, check=True, cwd=None):
        result = subprocess.run([str(cli_binary), *map(str, args)], capture_output=True,
                                text=True, cwd=cwd)
        if check and result.returncode != 0:
            raise AssertionError(f"tofkit {' '.join(map(str, args))} failed:\n{result.stderr}")
        return result

    return run


def cli_error(result):
    """The message of `tofkit CMD: error: MESSAGE` on stderr."""
    assert result.returncode == 1, result.stderr
    prefix, _, message = result.stderr.partition(": error: ")
    assert prefix.startswith("tofkit"), result.stderr
    return message.rstrip("\n")


def pauses_of_another_thread(work):
    """Runs work() in a thread while this one ticks as fast as it can; returns
    the gaps between ticks (s) and how long work() ran meanwhile (s). With the
    GIL released during work(), the largest gap stays far below that time;
    held, one gap spans nearly all of it. Both are measured in the same run,
    so a loaded machine (which slows work() and lengthens the scheduler's
    pauses alike) does not decide the comparison."""
    import sys
    import threading
    import time

    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    try:
        ticks = []
        ran = []

        def timed():
            start = time.perf_counter()
            work()
            ran.append(time.perf_counter() - start)

        worker = threading.Thread(target=timed)
        worker.start()
        while worker.is_alive():
            ticks.append(time.perf_counter())
        worker.join()
    finally:
        sys.setswitchinterval(old_interval)
    return [b - a for a, b in zip(ticks, ticks[1:])], ran[0]
