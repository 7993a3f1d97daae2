"""The history's input: run folders (given, or found below a store folder), each read once with the
gate's loader, placed at its commit, and its rows labelled with the ladder rung they ran."""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

from bench.gate.load import load_run, run_fingerprint
from bench.protocol.results import MANIFEST, run_progress
from bench.protocol.vocabulary import canonical_params

RUNG_COLUMN = "rung"   # a row's declared override, when the runner records it (else read from the manifest)
MACHINE_FIELDS = ("cpu", "cores", "gl_renderer", "gl_version", "stage_clock")
DIRTY = "-dirty"


@dataclass
class HistoryRun:
    """One run folder placed in the history."""
    path: Path
    commit: str               # as the manifest records it ("<sha>" or "<sha>-dirty")
    created: _dt.datetime | None
    machine: str              # fingerprint: a short hash of MACHINE_FIELDS
    machine_label: str
    rows: list = field(default_factory=list)   # result rows, each with its "rung" (canonical JSON)
    link: Path | None = None  # the run's report (report/index.html, else summary.html, else the folder)

    @property
    def base_commit(self) -> str:
        return self.commit.removesuffix(DIRTY)


# ---------------------------------------------------------------------------- finding run folders
def is_run_folder(path: Path) -> bool:
    return path.is_dir() and (path / MANIFEST).is_file() and any(
        (path / name).is_file() for name in ("results.csv", "results.parquet"))


def store_run_folders(store: Path) -> list[Path]:
    """Every run folder below `store` (links not followed: runs/latest names a run found anyway)."""
    store = Path(store)
    if not store.is_dir():
        raise FileNotFoundError(f"history store not found: {store}")
    found = []
    stack = [store]
    while stack:
        folder = stack.pop()
        if is_run_folder(folder):
            found.append(folder)
            continue   # a run's images and report are not runs
        for child in sorted(folder.iterdir(), reverse=True):
            if child.is_dir() and not child.is_symlink():
                stack.append(child)
    if not found:
        raise FileNotFoundError(f"history store {store} holds no run folder (a folder with {MANIFEST} and results)")
    return sorted(found)


# ---------------------------------------------------------------------------- one run
def machine_fingerprint(manifest: dict) -> tuple[str, str]:
    """(fingerprint, label) of the machine a run timed on: timing series are per fingerprint."""
    machine = manifest.get("machine") or {}
    facts = {k: machine.get(k) for k in MACHINE_FIELDS}
    digest = hashlib.sha256(json.dumps(facts, sort_keys=True, default=str).encode()).hexdigest()[:8]
    label = f"{machine.get('cpu') or '?'}, {machine.get('cores') or '?'} cores, {machine.get('gl_renderer') or '?'}"
    return digest, label


def _created(manifest: dict) -> _dt.datetime | None:
    try:
        stamp = _dt.datetime.fromisoformat(str(manifest.get("created")))
    except ValueError:
        return None
    return stamp if stamp.tzinfo else stamp.replace(tzinfo=_dt.UTC)


def _plain_number(value):
    """Numbers in one form (64 and 64.0 alike) so that declared and resolved parameters compare."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return value
    return int(value) if math.isfinite(value) and float(value).is_integer() else float(value)


def _normalised(params: dict) -> str:
    return canonical_params({str(k): _plain_number(v) for k, v in params.items()})


def declared_rungs(manifest: dict, method: str) -> list[dict]:
    """The parameter overrides `method` ran at in this run, as declared: its --param sets, else its
    ladder (unless --defaults-only), else the defaults ({})."""
    arguments = manifest.get("arguments") or {}
    given = (arguments.get("params") or {}).get(method)
    if given:
        return [dict(s) for s in given]
    ladder = ((manifest.get("methods") or {}).get(method) or {}).get("ladder") or []
    if arguments.get("ladders", True) and ladder:
        return [dict(r) for r in ladder]
    return [{}]


def row_rung(rec: dict, manifest: dict) -> str:
    """The rung a row ran, as its declared override (canonical JSON; "{}" for the defaults): the
    row's own `rung` cell, else the declared override whose resolution (the declared defaults
    updated by it) is the row's parameters, else the parameters that differ from the defaults."""
    own = rec.get(RUNG_COLUMN)
    if isinstance(own, str) and own.strip():
        return canonical_params(own)
    try:
        params = json.loads(canonical_params(rec.get("params")))
    except ValueError:
        params = {}
    method = str(rec.get("method"))
    defaults = ((manifest.get("methods") or {}).get(method) or {}).get("defaults") or {}
    wanted = _normalised(params)
    for override in declared_rungs(manifest, method):
        if _normalised({**defaults, **override}) == wanted:
            return canonical_params(override)
    return canonical_params({k: v for k, v in params.items()
                             if k not in defaults or _plain_number(defaults[k]) != _plain_number(v)})


def _report_link(path: Path) -> Path:
    for candidate in (path / "report" / "index.html", path / "summary.html"):
        if candidate.is_file():
            return candidate
    return path


def load_history_runs(paths, notes: list) -> list[HistoryRun]:
    """The runs of the history: each folder read by the gate's loader (a folder that is not a run
    folder is an error naming it); unfinished runs, runs without a commit and a run listed twice
    (a copy keeps its run id) are left out, each with a note."""
    runs, seen = [], {}
    for path in map(Path, paths):
        df, manifest = load_run(path, "history")
        if not (path / MANIFEST).is_file():
            raise FileNotFoundError(f"history: {path} is not a run folder (no {MANIFEST}: its commit is unknown)")
        progress = run_progress(path)
        if not progress.complete:
            notes.append(f"{path} left out: {progress.describe()}")
            continue
        commit = str(manifest.get("git_commit") or "unknown")
        if commit == "unknown":
            notes.append(f"{path} left out: its manifest records no git commit")
            continue
        fingerprint = run_fingerprint(path, df, manifest)
        if fingerprint in seen:
            notes.append(f"{path} left out: the same run as {seen[fingerprint]}")
            continue
        seen[fingerprint] = path
        machine, label = machine_fingerprint(manifest)
        rows = []
        for rec in df.to_dict("records"):
            rec[RUNG_COLUMN] = row_rung(rec, manifest)
            rows.append(rec)
        runs.append(HistoryRun(path, commit, _created(manifest), machine, label, rows, _report_link(path)))
    return runs


# ---------------------------------------------------------------------------- commit order
def git_repository(start: Path | None) -> Path | None:
    """The top folder of the git repository containing `start`, or None."""
    if start is None:
        return None
    try:
        out = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=start, capture_output=True, text=True,
                             timeout=30, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return Path(out.stdout.strip()) if out.returncode == 0 and out.stdout.strip() else None


def git(repo: Path, *args: str) -> str:
    """A read-only git command's output; ValueError (one line) when it fails."""
    out = subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, timeout=120, check=False)
    if out.returncode != 0:
        raise ValueError(f"git {' '.join(args)} failed in {repo}: {' '.join(out.stderr.split())}")
    return out.stdout


def resolve_commit(repo: Path, name: str) -> str | None:
    """The full sha of a commit name in `repo`, or None when the repository does not have it."""
    try:
        return git(repo, "rev-parse", "--verify", "--quiet", f"{name}^{{commit}}").strip() or None
    except ValueError:
        return None


def has_commits(repo: Path, runs: list[HistoryRun]) -> bool:
    """Whether `repo` has the commit of every run."""
    return all(resolve_commit(repo, c) for c in dict.fromkeys(r.base_commit for r in runs))


def order_runs(runs: list[HistoryRun], repo: Path | None, notes: list) -> tuple[list[str], str]:
    """The history's commits, oldest first, and how they were ordered: by git ancestry (topological
    order) when `repo` has every commit, else by the date of each commit's first run. A dirty
    commit (uncommitted edits) follows its clean commit."""
    first_seen: dict = {}
    for run in runs:
        stamp = run.created or _dt.datetime.max.replace(tzinfo=_dt.UTC)
        first_seen[run.commit] = min(first_seen.get(run.commit, stamp), stamp)
    bases = list(dict.fromkeys(r.base_commit for r in runs))
    by_date = sorted(first_seen, key=lambda c: (first_seen[c], c))
    if repo is None or not bases:
        return by_date, "date"
    full = {b: resolve_commit(repo, b) for b in bases}
    missing = [b for b, f in full.items() if f is None]
    if missing:
        notes.append(f"{len(missing)} commit(s) are not in {repo} ({', '.join(m[:10] for m in missing[:3])}): "
                     f"ordered by date")
        return by_date, "date"
    listed = git(repo, "rev-list", "--topo-order", "--reverse", *sorted(set(full.values()))).split()
    rank = {sha: i for i, sha in enumerate(listed)}
    ordered = sorted(first_seen, key=lambda c: (rank[full[c.removesuffix(DIRTY)]],
                                                c.endswith(DIRTY), first_seen[c]))
    return ordered, "git ancestry"
