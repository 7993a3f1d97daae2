"""A run's plan: its rows (jobs), its run folder, and what an earlier run into the same folder left.

* Jobs run grouped by scene and view (`view_groups`): a scene is uploaded once, a view's shared
  passes are rendered once.
* An existing `--out` is merged, not replaced (`merge_existing`): rows of the folder that this run
  does not produce (other methods, resolutions, parameter sets) are kept, and their images are
  moved aside when this run's rows need the same image folder.
* `RunState` (`run_state.json`) records which rows the current invocation finished, so an
  interrupted run resumes without redoing them, a `force=True` run too (without `force`, every
  finished row of the folder is reused); and how many rows it planned and recorded, and whether
  it finished: the one notion of a finished run, which report and gate read
  (bench.protocol.results.run_progress).
* `RunFolderLock`: a run folder has one writer at a time. The run holds an exclusive `flock` on
  `<run>/.gibench-run.lock` from before its first write to its end; a second run into the folder
  is refused with one line naming the holder (bad input, exit 2), not made to wait: a run queued
  behind another for minutes, with no sign of it, looks hung, and two runs into one folder are
  most often a mistake (the same `--out` in two scripts). Merges then never lose rows: each run
  reads the folder's rows after taking the lock. The kernel drops the lock when its holder dies.
  A folder that vanishes or is replaced during the run (`check`) ends it with `RunFolderLost`.
"""
from __future__ import annotations

import datetime as _dt
import fcntl
import hashlib
import json
import os
import shutil
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from bench.model.scene import SceneError
from bench.protocol import results as store
from bench.protocol.results import RUN_LOCK, RUN_STATE
from bench.protocol.vocabulary import Status, row_identity
from bench.run.config import RunConfig, expand_param_sets


@dataclass(frozen=True)
class Job:
    """One row to produce: a method at one parameter set (`index` into its sets) on one view."""
    scene: str
    view: str
    method: str
    index: int
    params: dict


def make_jobs(cfg: RunConfig, scenes: dict) -> list[Job]:
    jobs = []
    for scene_name, scene in scenes.items():
        for view in cfg.views or sorted(scene.cameras):
            if view not in scene.cameras:
                raise SceneError(f"scene '{scene_name}' has no camera '{view}'; cameras: {sorted(scene.cameras)}")
            for method in cfg.methods:
                for index, pset in enumerate(expand_param_sets(cfg, method)):
                    jobs.append(Job(scene_name, view, method, index, pset))
    return jobs


def view_groups(jobs: list[Job]) -> list[list[Job]]:
    """Consecutive jobs of one (scene, view): the runner's unit of shared passes."""
    groups: list = []
    for job in jobs:
        if groups and (groups[-1][0].scene, groups[-1][0].view) == (job.scene, job.view):
            groups[-1].append(job)
        else:
            groups.append([job])
    return groups


def image_folder(method_name: str, params: dict, cls) -> str:
    """`<method>` for default parameters, `<method>@<hash>` for other parameter sets."""
    defaults = {k: p.default for k, p in cls.params.items()}
    if params == defaults:
        return method_name
    return f"{method_name}@{hashlib.sha256(store.params_json(params).encode()).hexdigest()[:8]}"


# ---------------------------------------------------------------------------- the run folder
def default_run_dir(root: Path = Path("runs")) -> Path:
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = root / stamp
    n = 1
    while path.exists():
        n += 1
        path = root / f"{stamp}-{n}"
    return path


def point_latest(run_dir: Path) -> None:
    latest = run_dir.parent / "latest"
    tmp = run_dir.parent / f".latest.tmp{os.getpid()}"
    try:
        if tmp.is_symlink() or tmp.exists():
            tmp.unlink()
        tmp.symlink_to(run_dir.name)
        os.replace(tmp, latest)
    except OSError:
        pass


def prepare_run_dir(run_dir: Path) -> None:
    """Create the run folder (or a report's); an unusable --out is bad input (ValueError, one line)."""
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"--out {run_dir} is a file, not a run folder")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / f".write-test{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise ValueError(f"--out {run_dir} is not a writable folder ({exc.strerror or exc})") from None


class RunFolderLost(OSError):
    """The run folder vanished or was replaced while the run wrote it: the run is incomplete."""


class RunFolderLock:
    """The owner of a run folder: an exclusive flock on `<run>/.gibench-run.lock` (see the module's
    docstring). The file names the holder while it is held and is emptied on release, so two
    finished run folders still compare file by file."""
    PROBE_GRACE_S = 1.0   # a reader's probe (bench.protocol.results.run_folder_locked) holds it for microseconds

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / RUN_LOCK
        self._file = None
        self._identity = None   # (folder, lock file) as (st_dev, st_ino) when the lock was taken

    def acquire(self) -> None:
        """Take the lock; another run holding it is bad input (ValueError, one line)."""
        handle = open(self.path, "a+")   # a+ creates it without emptying the holder's note
        deadline = time.monotonic() + self.PROBE_GRACE_S
        while True:
            try:
                fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() < deadline:
                    time.sleep(0.05)
                    continue
                handle.seek(0)
                holder = " ".join(handle.read().split()) or "holder unknown"
                handle.close()
                raise ValueError(f"--out {self.run_dir} is being written by another gibench run ({holder}); "
                                 f"wait for it to finish or choose another --out") from None
        handle.seek(0)
        handle.truncate()
        command = " ".join(sys.argv)[:300]
        handle.write(f"pid {os.getpid()} on {socket.gethostname()} since "
                     f"{_dt.datetime.now().isoformat(timespec='seconds')}: {command}\n")
        handle.flush()
        self._file = handle
        folder, lock = os.stat(self.run_dir), os.fstat(handle.fileno())
        self._identity = ((folder.st_dev, folder.st_ino), (lock.st_dev, lock.st_ino))

    def check(self) -> None:
        """RunFolderLost when the folder (or its lock file) is no longer the one this run locked."""
        if self._identity is None:
            return
        try:
            folder, lock = os.stat(self.run_dir), os.stat(self.path)
            same = ((folder.st_dev, folder.st_ino), (lock.st_dev, lock.st_ino)) == self._identity
        except OSError:
            same = False
        if not same:
            raise RunFolderLost(f"{self.run_dir} vanished or was replaced while this run wrote it: the run is "
                                f"incomplete; re-run the same command to repair it")

    def release(self) -> None:
        if self._file is None:
            return
        try:
            self._file.seek(0)
            self._file.truncate()
        except OSError:   # a vanished folder: nothing to empty
            pass
        self._file.close()   # closing drops the flock
        self._file = None


def existing_rows(run_dir: Path) -> list[dict]:
    """Rows already in the run folder (a corrupt table is an error, never silently dropped)."""
    try:
        df = store.load_results(run_dir)
    except FileNotFoundError:
        return []
    return df.to_dict("records")


def merge_existing(run_dir: Path, existing: list[dict], produced: list[tuple]) -> list[dict]:
    """The folder's rows this run does not produce (`produced`: (row identity, image dir) of each
    job), their images moved out of the way of this run's rows where the folders coincide."""
    identities = {ident for ident, _ in produced}
    new_dirs = {image_dir for _, image_dir in produced}
    kept = []
    for rec in existing:
        if row_identity(rec) in identities:
            continue
        image_dir = rec.get("image_dir")
        if isinstance(image_dir, str) and image_dir in new_dirs:
            tag = str(rec.get("row_key") or hashlib.sha256(repr(row_identity(rec)).encode()).hexdigest())[:8]
            moved = f"{image_dir}@{tag}"
            src, dst = run_dir / image_dir, run_dir / moved
            if src.is_dir() and not dst.exists():
                shutil.move(str(src), str(dst))
            rec = dict(rec, image_dir=moved)
        kept.append(rec)
    return kept


# ---------------------------------------------------------------------------- resume
def resumable_rows(existing: list[dict], allowed: set | None) -> dict:
    """Finished rows of the folder by (row_key, image_dir); `allowed` limits them to those keys."""
    out = {}
    for rec in existing:
        key = (rec.get("row_key"), rec.get("image_dir"))
        if not isinstance(key[0], str) or not isinstance(key[1], str):
            continue
        if allowed is not None and f"{key[0]}|{key[1]}" not in allowed:
            continue
        if Status.kind(rec.get("status")) in Status.FINISHED:
            out[key] = rec
    return out


def invocation_hash(cfg: RunConfig, scenes: dict) -> str:
    payload = {k: v for k, v in cfg.__dict__.items() if k not in ("scenes", "progress", "out")}
    payload["scenes"] = [(name, s.content_hash()) for name, s in scenes.items()]
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:24]


class RunState:
    """`run_state.json`: the invocation (a hash of its arguments and scenes), whether it finished,
    how many rows it planned and recorded, and the rows it finished ("row_key|image_dir")."""

    def __init__(self, run_dir: Path):
        self.path = Path(run_dir) / RUN_STATE
        self.previous = self._read()
        self.state: dict = {}

    def _read(self) -> dict:
        try:
            state = json.loads(self.path.read_bytes())
        except (OSError, ValueError):
            return {}
        return state if isinstance(state, dict) else {}

    def resumable(self, existing: list[dict], invocation: str, force: bool) -> dict:
        """The folder's rows this invocation need not render again."""
        if not force:
            return resumable_rows(existing, None)
        if self.previous.get("invocation") == invocation and not self.previous.get("finished", True):
            # the same forced command, interrupted: its finished rows are not re-rendered
            return resumable_rows(existing, set(self.previous.get("done") or []))
        return {}

    def start(self, invocation: str, planned: int) -> None:
        self.state = {"invocation": invocation, "finished": False, "planned": int(planned), "recorded": 0, "done": []}
        self._write()

    def mark_done(self, row: dict, write: bool = True) -> None:
        """Count a recorded row; note it as finished unless it failed (a resumed run tries it again).
        `write=False` defers the file to the next write (a row that cost nothing to produce)."""
        self.state["recorded"] += 1
        if not Status.is_failed(row.get("status")) and isinstance(row.get("row_key"), str):
            self.state["done"].append(f"{row['row_key']}|{row['image_dir']}")
        if write:
            self._write()

    def finish(self) -> None:
        self.state["finished"] = True
        self._write()

    def _write(self) -> None:
        store.atomic_write_text(self.path, json.dumps(self.state, indent=1))
