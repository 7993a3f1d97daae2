"""The history's list of changes as plain text (CI logs) and Markdown: newest commit first, the
changes each commit starts, machine-wide steps said as such."""
from __future__ import annotations


def short(commit: str) -> str:
    return commit[:10] + ("-dirty" if commit.endswith("-dirty") else "")


def commit_range(change) -> str:
    """"a1b2c3d4e5..f6a7b8c9d0 (3 commits)": where the step happened."""
    span = f"{short(change.commit_before)}..{short(change.commit_after)}"
    n = change.commits_between
    return span if n is None else f"{span} ({n} commit{'s' if n != 1 else ''})"


def change_line(change) -> str:
    """One change as one line."""
    series = change.series
    if change.machine_wide:
        what = f"machine-wide: every timed row {change.verdict.split()[1]} on {series.machine_label}"
        what += f" ({len(change.rows)} rows)" if change.rows else ""
    else:
        what = f"{change.verdict}: {series.row_label} {series.metric}"
        if series.machine:
            what += f" on machine {series.machine}"
    levels = f"{change.level_before:.4g} -> {change.level_after:.4g}"
    notes = f"; {'; '.join(change.notes)}" if change.notes else ""
    return f"{what}: {levels}, {change.change_text()}, p {change.p_value:.2g}, in {commit_range(change)}{notes}"


def summary_line(history) -> str:
    regressions = history.regressions()
    machine = [c for c in history.changes if c.machine_wide]
    improvements = [c for c in history.changes if c.verdict == "improvement"]
    return (f"{len(history.runs)} runs over {len(history.commits)} commits (ordered by {history.ordered_by}), "
            f"{len(history.series)} series: {len(regressions)} regression(s), {len(improvements)} improvement(s), "
            f"{len(machine)} machine-wide step(s)")


def check_line(history) -> str:
    newest = history.newest_commit
    starting = history.starting_at(newest) if newest else []
    if starting:
        return f"check: FAIL: the newest commit {short(newest)} starts {len(starting)} regression(s)"
    return f"check: ok: the newest commit {short(newest) if newest else '-'} starts no regression"


def history_text(history) -> str:
    lines = [summary_line(history)]
    for commit, changes in history.by_commit():
        lines.append("")
        lines.append(f"commit {short(commit)}:")
        lines += [f"  {change_line(c)}" for c in changes]
    if history.notes:
        lines.append("")
        lines += [f"note: {n}" for n in history.notes]
    lines.append("")
    lines.append(check_line(history))
    return "\n".join(lines) + "\n"


def history_markdown(history) -> str:
    lines = ["# gibench history", "", summary_line(history), ""]
    for commit, changes in history.by_commit():
        lines.append(f"## {short(commit)}")
        lines.append("")
        lines += [f"- {change_line(c)}" for c in changes]
        lines.append("")
    if not history.changes:
        lines += ["No change point.", ""]
    if history.notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in history.notes] + [""]
    lines.append(check_line(history))
    return "\n".join(lines) + "\n"
