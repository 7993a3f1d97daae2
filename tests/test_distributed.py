"""Rows as Dask tasks (bench.distributed): a 2-process local cluster gives the serial run's rows
and bit-identical images, and a worker killed mid-run loses nothing."""
import json
import os
import signal
import threading
import time

import numpy as np
import pandas as pd
import pytest

from bench.imageio import read_exr
from bench.runner import RunConfig, run
from tests.conftest import make_open_box

pytest.importorskip("distributed")

COMPARED = ("scene", "view", "method", "params", "status", "row_key", "image_dir", "seed", "width", "height")


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))


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
    for a, b in zip(serial.to_dict("records"), dist.to_dict("records")):
        for comp in ("direct", "indirect", "combined"):
            assert np.array_equal(read_exr(rs.run_dir / a["image_dir"] / f"{comp}.exr"),
                                  read_exr(rd.run_dir / b["image_dir"] / f"{comp}.exr")), (a["method"], comp)
    files = lambda d: sorted(p.relative_to(d).as_posix() for p in d.rglob("*") if p.is_file())
    assert files(rs.run_dir) == files(rd.run_dir)
    phases = json.loads((rd.run_dir / "manifest.json").read_text())["phases_s"]
    assert phases["timing"] > 0


def test_a_killed_worker_loses_nothing(tmp_path):
    import dask
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
    # a dead worker's timing-semaphore lease expires quickly here, so the retried task is not held up
    with dask.config.set({"distributed.scheduler.locks.lease-timeout": "2s",
                          "distributed.scheduler.locks.lease-validation-interval": "0.5s"}):
        thread.start()
        df, runner = run(cfg, log=lambda m: None)
    thread.join(timeout=5)
    assert killed, "no worker was killed: the test did not exercise a failure"
    assert len(df) == 8 and set(df["status"]) <= {"ok"}, df[["method", "status"]]
    for rec in df.to_dict("records"):
        assert (runner.run_dir / rec["image_dir"] / "combined.exr").is_file()
