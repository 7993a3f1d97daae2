"""`gibench` command line: run, sweep, stress, list, report, gate, history, bisect, reference, manuals,
cost-model, new-method, check-method (one module each).

Exit codes: 0 success; 1 nothing useful produced (every row of a run failed), a run that could
not finish (its --out vanished), a gate regression, a history --check whose newest commit starts a
regression, a stress failure, an out-of-date manual, a method failing check-method, or a missing
dependency (Mitsuba); 2 bad input (one line naming the culprit, before any work: an option outside
its declared range (bench.cli.options), a name given twice, a name unsafe in a
path, a scene, a parameter, an unusable --out, a run folder another run is writing, a corrupt
results table, a run listed twice or unfinished in a gate, a gate that compared nothing); 130
interrupted (Ctrl-C or SIGTERM: re-run the same command to resume, with or without --force).
"""
from __future__ import annotations

import sys

from bench.cli import (bisect, check_method, cost_model, gate, history, listing, manuals, new_method, reference, report,
                       run, stress, sweep)
from bench.cli.options import OneLineParser
from bench.cli.options import param_sets as _param_sets  # noqa: F401  (the --param grammar, tested as such)

COMMANDS = (run, sweep, stress, listing, report, gate, history, bisect, reference, manuals, cost_model, new_method,
            check_method)


def main(argv=None) -> int:
    parser = OneLineParser(prog="gibench", description="Benchmark real-time diffuse GI against Mitsuba 3.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        print("gibench: interrupted; re-run the same command to resume", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, KeyError) as exc:
        # Bad input: one line naming the culprit, no traceback.
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"gibench: {' '.join(str(msg).split())}", file=sys.stderr)
        return 2
    except OSError as exc:  # the disk refused (full, read-only, permissions): one line, no traceback
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"gibench: {exc.strerror or exc}{where}", file=sys.stderr)
        return 1
