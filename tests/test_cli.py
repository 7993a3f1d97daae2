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


# ---------------------------------------------------------------------------- issue #15: exit codes
@pytest.fixture
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))


def _one_line_err(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    return err


def test_every_row_failed_exits_non_zero(tmp_path, capsys, monkeypatch, private_cache):
    from bench.protocol.registry import load_method

    direct = load_method("direct")

    class Crashes(direct):
        def prepare(self, *a, **k):
            raise RuntimeError("shader did not compile")

    monkeypatch.setattr("bench.run.serial.load_method", lambda name: Crashes)
    args = ["run", "--scenes", "cornell_spot", "--methods", "direct", "--res", "16x12", "--frames", "1",
            "--warmup", "1", "--no-reference", "--no-progress", "--out", str(tmp_path / "r")]
    assert main(args) == 1
    assert "every row failed (1 rows)" in capsys.readouterr().err


def test_param_of_a_method_not_in_the_run_is_bad_input(tmp_path, capsys, private_cache):
    assert main(["run", "--scenes", "cornell_spot", "--methods", "direct", "--param", "flc.N_avg=64",
                 "--no-progress", "--out", str(tmp_path / "r")]) == 2
    assert "flc not in this run" in _one_line_err(capsys)
    assert main(["run", "--scenes", "cornell_spot", "--methods", "direct,manylights", "--param",
                 "manylights.jitter_frames=0", "--no-progress", "--out", str(tmp_path / "r")]) == 2
    assert "jitter_frames" in _one_line_err(capsys)
    assert not (tmp_path / "r").exists()


def test_out_on_a_file_is_one_line(tmp_path, capsys, private_cache):
    (tmp_path / "f").write_text("x")
    assert main(["run", "--scenes", "cornell_spot", "--methods", "direct", "--no-progress", "--out",
                 str(tmp_path / "f")]) == 2
    assert "is a file, not a run folder" in _one_line_err(capsys)


def test_unsafe_scene_name_is_one_line(tmp_path, capsys, private_cache):
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 0 1\nf 1 2 3\n")
    (tmp_path / "s.toml").write_text('name = "../../escape"\n[[mesh]]\nfile = "q.obj"\n[[light]]\ntype = "point"\n'
                                     'position = [0, 1, 0]\nintensity = 1\n[camera.main]\neye = [0, 2, 2]\n'
                                     'target = [0, 0, 0]\n')
    assert main(["run", "--scenes", str(tmp_path / "s.toml"), "--methods", "direct", "--no-progress", "--out",
                 str(tmp_path / "r")]) == 2
    assert "'../../escape' is not allowed" in _one_line_err(capsys)
    assert not (tmp_path.parent / "escape").exists()


def test_reference_build_without_mitsuba_is_one_line(capsys, monkeypatch):
    from reference import env
    monkeypatch.delitem(env._state, "mi", raising=False)
    monkeypatch.setitem(env._state, "error", "Mitsuba 3 is not installed (No module named 'mitsuba'): pip install mitsuba")
    assert main(["reference", "build", "--scenes", "cornell_spot", "--res", "16x12"]) == 1
    assert "Mitsuba 3 is not installed" in _one_line_err(capsys)


@pytest.mark.parametrize("extra, expected", [([], 1024), (["--quick"], 256), (["--quick", "--reference-spp", "512"], 512)])
def test_reference_cap_of_run_and_quick(monkeypatch, extra, expected):
    """`run` caps references at 1024 spp, `run --quick` (a first report in minutes) at 256,
    unless --reference-spp says otherwise."""
    import bench.cli as cli
    seen = {}

    class Stop(Exception):
        pass

    def fake_run(cfg, log=None):
        seen["cap"] = cfg.reference_spp_cap
        raise Stop
    import bench.run.serial
    monkeypatch.setattr(bench.run.serial, "run", fake_run)
    with pytest.raises(Stop):
        cli.main(["run", "--scenes", "cornell_spot", "--methods", "direct", "--no-progress"] + extra)
    assert seen["cap"] == expected


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_shadow_resolution_reaches_the_run_config(monkeypatch, command):
    """--shadow-resolution sets the shared shadow maps' tile side of `run` and `sweep`; unset, the
    runner sizes them from the image (RunConfig.shadow_resolution None)."""
    import bench.cli as cli
    import bench.run.serial
    seen = []

    class Stop(Exception):
        pass

    def fake_run(cfg, log=None):
        seen.append(cfg.shadow_resolution)
        raise Stop
    monkeypatch.setattr(bench.run.serial, "run", fake_run)
    base = [command, "--scenes", "cornell_spot", "--methods", "direct", "--no-progress"]
    for extra in (["--shadow-resolution", "2048"], []):
        with pytest.raises(Stop):
            cli.main(base + extra)
    assert seen == [2048, None]


@pytest.mark.parametrize("value", ["0", "9000", "big"])
def test_bad_shadow_resolution_is_one_line(capsys, value):
    with pytest.raises(SystemExit):
        main(["run", "--scenes", "cornell_spot", "--shadow-resolution", value])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "shadow resolution" in err and value in err
