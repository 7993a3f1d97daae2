"""Rows as Dask tasks (bench.run.cluster): a 2-process local cluster gives the serial run's rows
and bit-identical images, and a worker killed mid-run loses nothing."""
import json
import os
import signal
import threading
import time

import numpy as np
import pandas as pd
import pytest

from bench.model.imageio import read_exr
from bench.protocol.vocabulary import FRAME_STAT_IMAGES
from bench.run.serial import RunConfig, run
from tests.conftest import make_open_box

pytest.importorskip("distributed")

COMPARED = ("scene", "view", "method", "params", "status", "row_key", "image_dir", "seed", "width", "height")


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("GIBENCH_TIMING_LOCK", str(tmp_path / "timing.lock"))   # not shared with other runs


def config(tmp_path, out, **kw):
    base = dict(scenes=[make_open_box(), "cornell_spot"], methods=["direct", "manylights", "ssdo"], width=32,
                height=24, frames=2, warmup=1, out=tmp_path / out, references=False, progress=False, force=True)
    base.update(kw)
    return RunConfig(**base)


def test_two_workers_give_the_serial_rows_and_images(tmp_path):
    serial, rs = run(config(tmp_path, "serial"), log=lambda m: None)
    dist, rd = run(config(tmp_path, "dist", workers=2), log=lambda m: None)
    assert list(serial["status"]) == ["ok"] * 6
    pd.testing.assert_frame_equal(serial[list(COMPARED)].reset_index(drop=True), dist[list(COMPARED)].reset_index(drop=True))
    assert dist["worker"].nunique() >= 1 and dist["frame_ms"].notna().all()
    # the same fields: workers lend each view's shared passes to its rows as the serial runner does
    assert sorted(set(dist.columns) - {"worker"}) == sorted(serial.columns)
    assert dist["extra.shared_passes_reused"].astype(bool).tolist() == serial["extra.shared_passes_reused"].astype(bool).tolist()
    for a, b in zip(serial.to_dict("records"), dist.to_dict("records")):
        for comp in ("direct", "indirect", "combined") + FRAME_STAT_IMAGES:   # the error frames' statistics too
            assert np.array_equal(read_exr(rs.run_dir / a["image_dir"] / f"{comp}.exr"),
                                  read_exr(rd.run_dir / b["image_dir"] / f"{comp}.exr")), (a["method"], comp)
    files = lambda d: sorted(p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file())
    assert files(rs.run_dir) == files(rd.run_dir)
    phases = json.loads((rd.run_dir / "manifest.json").read_text())["phases_s"]
    assert phases["timing"] > 0


def test_a_killed_worker_loses_nothing(tmp_path):
    from distributed import get_client

    killed = []

    def kill_one_worker():
        # wait for the cluster's first finished row, then kill -9 a worker process (its task is retried)
        deadline = time.time() + 120
        while time.time() < deadline and not (tmp_path / "dist" / "results.csv").is_file():
            time.sleep(0.05)
        try:
            client = get_client()
        except ValueError:
            return
        pids = client.run(os.getpid)
        pid = sorted(pids.values())[0]
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)

    cfg = config(tmp_path, "dist", workers=2, methods=["direct", "manylights", "ssdo", "flc"])
    thread = threading.Thread(target=kill_one_worker, daemon=True)
    # the dead worker's timing lock (a flock) is released by the kernel: the retried task is not held up
    thread.start()
    df, runner = run(cfg, log=lambda m: None)
    thread.join(timeout=5)
    assert killed, "no worker was killed: the test did not exercise a failure"
    assert len(df) == 8 and set(df["status"]) <= {"ok"}, df[["method", "status"]]
    for rec in df.to_dict("records"):
        assert (runner.run_dir / rec["image_dir"] / "combined.exr").is_file()


def test_timed_rows_never_overlap_even_when_a_row_holds_the_gil(tmp_path):
    """A GL call can hold the GIL for minutes (llvmpipe, 10M triangles). A Dask Semaphore's lease,
    refreshed by the starved event loop, then expired and a second row rendered beside the first;
    the host's flock does not depend on the worker answering."""
    import dask

    from bench.run import cluster as dist

    def hold_gil_under_the_lock(n):
        import os
        import time as _time
        from bench.run.cluster import timing_lock
        with timing_lock():
            t0 = _time.time()
            sum(range(n))   # one C call: the GIL is held throughout
            return t0, _time.time(), os.getpid()

    # short Dask lease timeouts: what expired the Semaphore's leases, the flock must not care
    with dask.config.set({"distributed.scheduler.locks.lease-timeout": "0.5s",
                          "distributed.scheduler.locks.lease-validation-interval": "0.1s"}):
        client, cluster = dist.open_client(workers=2)
        try:
            futures = [client.submit(hold_gil_under_the_lock, 30_000_000 + i, pure=False) for i in range(4)]
            windows = sorted(client.gather(futures))
        finally:
            dist.close_client(client, cluster)
    assert len({pid for _, _, pid in windows}) == 2, "the tasks did not run on both workers"
    for (s0, e0, _), (s1, e1, _) in zip(windows, windows[1:]):
        assert s1 >= e0, f"two timed sections overlapped: {windows}"


def test_timing_lock_is_exclusive_and_freed_when_its_holder_is_killed(tmp_path):
    import fcntl
    import subprocess
    import sys

    from bench.run.cluster import timing_lock, timing_lock_path

    path = timing_lock_path()
    assert path == tmp_path / "timing.lock"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time\nfrom bench.run.cluster import timing_lock\n"
                               "with timing_lock():\n    print('held', flush=True)\n    time.sleep(120)\n"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        fd = os.open(path, os.O_RDONLY)
        try:
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
    finally:
        holder.kill()
        holder.wait(timeout=30)
    got = threading.Event()

    def take():
        with timing_lock():
            got.set()

    thread = threading.Thread(target=take, daemon=True)
    thread.start()
    assert got.wait(timeout=20), "the lock of a killed holder was not released"
    with pytest.raises(ValueError, match="timing lock"):
        with timing_lock(tmp_path / "no_such_folder" / "timing.lock"):
            pass


def test_a_row_the_cluster_drops_is_submitted_again(tmp_path, monkeypatch):
    """A task the scheduler forgets (its future cancelled, as after a killed worker: "cancelled for
    reason: already forgotten") is submitted again: here every row's first task is cancelled on
    submission and every row still ends ok."""
    from bench.run import cluster as dist
    opened = dist.open_client
    cancelled = []

    def open_dropping_client(scheduler=None, workers=None):
        client, cluster = opened(scheduler, workers)
        submit = client.submit

        def submit_then_drop(*args, **kwargs):
            fut = submit(*args, **kwargs)
            if "-again" not in kwargs.get("key", ""):
                client.cancel(fut)
                cancelled.append(kwargs.get("key"))
            return fut
        client.submit = submit_then_drop
        return client, cluster
    monkeypatch.setattr(dist, "open_client", open_dropping_client)
    df, runner = run(config(tmp_path, "dist", workers=1, scenes=[make_open_box()], methods=["direct", "ssdo"]),
                     log=lambda m: None)
    assert len(cancelled) == 2
    assert list(df["status"]) == ["ok", "ok"], df[["method", "status"]]
