"""A run folder's owner and its one notion of a finished run (issue #27): a second writer is refused,
timing is serialised between gibench processes of a host, SIGTERM saves and says how to resume, a
vanished folder is an incomplete run, bad input leaves no folder, and report and gate read whether
a run finished from `run_state.json`."""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from bench.cli import main
from bench.protocol.results import run_progress
from tests.conftest import make_open_box

REPO = Path(__file__).resolve().parents[1]
TINY = ["--res", "32x24", "--frames", "1", "--warmup", "1", "--no-reference", "--no-progress", "--defaults-only",
        "--timing-budget", "0"]


@pytest.fixture(autouse=True)
def private_cache_and_lock(tmp_path, monkeypatch):
    """A cache and a timing lock of the test's own: other gibench processes of the host do not wait for it."""
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("GIBENCH_TIMING_LOCK", str(tmp_path / "timing.lock"))


def _one_line(text: str) -> str:
    text = text.strip()
    assert text.count("\n") == 0 and "Traceback" not in text, text
    return text


def _gibench(args: list, **kw) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.Popen([sys.executable, "-m", "bench.cli", *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


def _wait_for(predicate, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


class HeldTimingLock:
    """The host's timing lock held by this test process: a gibench run waits at its first row."""

    def __init__(self, path: Path):
        self.fd = os.open(path, os.O_RDONLY | os.O_CREAT)
        fcntl.flock(self.fd, fcntl.LOCK_EX)

    def release(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


# ---------------------------------------------------------------------------- two real processes
@pytest.mark.gl
def test_second_writer_is_refused_sigterm_resumes_and_timing_waits(tmp_path):
    """Run A holds --out (and waits for the host's timing lock, held here): run B into the same --out
    is refused with one line (exit 2) and writes nothing; report and gate see A as running; SIGTERM
    ends A with the resume line (exit 130) and an unfinished state; A again finishes once the timing
    lock is free, its first row recording the wait."""
    out = tmp_path / "r"
    command = ["run", "--scenes", "cornell_spot", "--methods", "direct,manylights", *TINY, "--out", str(out)]
    lock = HeldTimingLock(tmp_path / "timing.lock")
    try:
        a = _gibench(command)
        _wait_for(lambda: (out / "run_state.json").is_file())
        b = _gibench(["run", "--scenes", "cornell_spot", "--methods", "direct", *TINY, "--force", "--out", str(out)])
        b_out, b_err = b.communicate(timeout=120)
        assert b.returncode == 2, b_err
        assert "is being written by another gibench run (pid " in _one_line(b_err)
        assert not (out / "images").exists() and not (out / "results.csv").exists()   # B wrote nothing
        progress = run_progress(out)
        assert progress.running and not progress.complete and progress.planned == 2
        assert progress.describe() == "incomplete: 0 of 2 rows (still running)"

        a.send_signal(15)
        a_out, a_err = a.communicate(timeout=60)
        assert a.returncode == 130 and _one_line(a_err) == "gibench: interrupted; re-run the same command to resume"
        assert json.loads((out / "run_state.json").read_text())["finished"] is False

        first_id = json.loads((out / "manifest.json").read_text())["run_id"]
        state_written = (out / "run_state.json").stat().st_mtime_ns
        again = _gibench(command)
        _wait_for(lambda: json.loads((out / "manifest.json").read_text())["run_id"] != first_id
                  and (out / "run_state.json").stat().st_mtime_ns != state_written)
        time.sleep(0.8)   # its first row waits for the timing lock meanwhile
    finally:
        lock.release()
    a_out, a_err = again.communicate(timeout=120)
    assert again.returncode == 0, a_err
    assert run_progress(out).complete and not run_progress(out).running
    df = pd.read_csv(out / "results.csv")
    assert list(df["status"]) == ["ok", "ok"]
    assert df["timing_lock_wait_ms"].iloc[0] > 400   # the first row waited for the lock
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["timing_lock"]["rows_waited"] >= 1
    assert (out / ".gibench-run.lock").read_text() == ""   # released: the holder's note is gone


# ---------------------------------------------------------------------------- in process
@pytest.mark.gl
def test_vanished_out_is_an_incomplete_run(tmp_path, capsys, monkeypatch):
    """The folder removed after the first row: exit non-zero, one line saying incomplete and re-run;
    also when the next rows come from the row cache, whose restore re-creates the folder (it exited 0)."""
    from bench.run import serial
    real = serial.Runner.record

    def record_then_vanish(self, row, **kw):
        real(self, row, **kw)
        if len(self.rows) == 1:
            shutil.rmtree(self.run_dir)

    monkeypatch.setattr(serial.Runner, "record", record_then_vanish)
    for name in ("cold-cache", "warm-cache"):
        code = main(["run", "--scenes", "cornell_spot", "--methods", "direct,manylights", *TINY,
                     "--out", str(tmp_path / name)])
        err = _one_line(capsys.readouterr().err)
        assert code != 0, name
        assert "vanished or was replaced" in err and "incomplete" in err and "re-run the same command" in err


@pytest.mark.parametrize("scenes, views, culprit", [
    ("no_such_scene", None, "unknown scene 'no_such_scene'"),
    ("missing.toml", None, "'missing.toml' not found"),
    ("cornell_spot", "nope", "has no camera 'nope'"),
])
def test_bad_input_leaves_no_out_folder(tmp_path, capsys, scenes, views, culprit):
    args = ["run", "--scenes", scenes, "--methods", "direct", *TINY, "--out", str(tmp_path / "r")]
    assert main(args + (["--views", views] if views else [])) == 2
    assert culprit in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "r").exists()


@pytest.fixture
def interrupted_run(tmp_path, monkeypatch):
    """A run of two rows interrupted after its first (tests.test_runner's interruption)."""
    from bench.run.serial import RunConfig, run
    from tests.test_runner import interrupt_the_second_row
    real = interrupt_the_second_row(monkeypatch)
    out = tmp_path / "interrupted"
    with pytest.raises(KeyboardInterrupt):
        run(RunConfig(scenes=[make_open_box()], methods=["direct", "manylights"], width=32, height=24, frames=2,
                      warmup=1, out=out, references=False, progress=False), log=lambda m: None)
    from bench.run import serial
    monkeypatch.setattr(serial.Runner, "_run_row", real)
    return out


@pytest.mark.gl
def test_report_and_gate_read_one_notion_of_a_finished_run(interrupted_run, tmp_path, capsys):
    from bench.gate import compare_runs
    from reports import build_report
    progress = run_progress(interrupted_run)
    assert not progress.complete and not progress.running and (progress.recorded, progress.planned) == (1, 2)
    page = build_report(interrupted_run, tmp_path / "rep").read_text()
    assert "incomplete: 1 of 2 rows (interrupted or failed: re-run the same command to finish it)" in page

    finished = tmp_path / "finished"
    shutil.copytree(interrupted_run, finished)
    state = json.loads((finished / "run_state.json").read_text())
    (finished / "run_state.json").write_text(json.dumps(dict(state, finished=True)))
    assert "incomplete" not in build_report(finished, tmp_path / "rep2").read_text()

    assert main(["gate", str(finished), str(interrupted_run)]) == 2
    err = _one_line(capsys.readouterr().err)
    assert f"candidate run {interrupted_run} is incomplete: 1 of 2 rows" in err and "--allow-incomplete" in err
    res = compare_runs(finished, interrupted_run, allow_incomplete=True)
    assert res.exit_code == 0 and "1 incomplete run(s)" in res.verdict()
    assert any("incomplete: 1 of 2 rows" in n for n in res.notes)


@pytest.mark.gl
def test_report_never_writes_into_the_run(interrupted_run, tmp_path, capsys):
    """The report's own time goes to its output folder; an output folder it cannot write is one line."""
    before = {p.name: p.read_bytes() for p in interrupted_run.iterdir() if p.is_file()}
    assert main(["report", str(interrupted_run), "--out", str(tmp_path / "rep")]) == 0
    capsys.readouterr()
    assert {p.name: p.read_bytes() for p in interrupted_run.iterdir() if p.is_file()} == before
    assert json.loads((tmp_path / "rep" / "report.json").read_text())["seconds"] >= 0
    (tmp_path / "file").write_text("x")
    assert main(["report", str(interrupted_run), "--out", str(tmp_path / "file" / "rep")]) == 2
    assert "is not a writable folder" in _one_line(capsys.readouterr().err)


def test_run_progress_reads_the_state_and_the_lock(tmp_path):
    """The states a reader meets: none (a folder by hand: taken as it is), unfinished, unreadable,
    finished but held by a run that has just started in it."""
    from bench.run.plan import RunFolderLock
    run_dir = tmp_path / "r"
    run_dir.mkdir()
    assert run_progress(run_dir).complete and run_progress(run_dir).finished is None
    (run_dir / "run_state.json").write_text(json.dumps({"finished": False, "done": ["a|b", "c|d"]}))
    assert run_progress(run_dir).describe() == ("incomplete: 2 rows recorded (interrupted or failed: "
                                                "re-run the same command to finish it)")
    (run_dir / "run_state.json").write_text("{")
    assert "is unreadable" in run_progress(run_dir).describe()
    (run_dir / "run_state.json").write_text(json.dumps({"finished": True, "planned": 2, "recorded": 2}))
    assert run_progress(run_dir).complete
    owner = RunFolderLock(run_dir)
    owner.acquire()
    try:
        progress = run_progress(run_dir)
        assert progress.running and not progress.complete and "writing it now" in progress.describe()
        with pytest.raises(ValueError, match="being written by another gibench run \\(pid "):
            RunFolderLock(run_dir).acquire()
    finally:
        owner.release()
    assert run_progress(run_dir).complete and (run_dir / ".gibench-run.lock").read_text() == ""
