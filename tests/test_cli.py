"""The command line: listing, bad input as one-line errors."""
import subprocess
import sys

import pytest

from bench.cli import _param_sets, main


def test_list_methods(capsys):
    assert main(["list", "methods"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names = [l.split()[0] for l in lines]
    assert {"direct", "manylights", "flc"} <= set(names)


def test_unknown_method_is_one_line(capsys):
    assert main(["run", "--scenes", "cornell_spot", "--methods", "direct,nope", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "unknown method(s) nope" in err


def test_bad_resolution():
    with pytest.raises(SystemExit):
        main(["run", "--res", "12by7"])


def test_param_grid():
    assert _param_sets(["flc.N_avg=64,128", "flc.mu=2.0"]) == {"flc": [{"N_avg": 64, "mu": 2.0}, {"N_avg": 128, "mu": 2.0}]}
    with pytest.raises(SystemExit):
        _param_sets(["N_avg=3"])


def test_console_script_runs():
    out = subprocess.run([sys.executable, "-m", "bench.cli", "list", "methods"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "manylights" in out.stdout
