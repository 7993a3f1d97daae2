"""The command line: listing, bad input as one-line errors."""
import subprocess
import sys

import pytest

from bench.cli import _param_sets, main
from tests.conftest import cli_run_config


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
    cfg = cli_run_config(monkeypatch, ["run", "--scenes", "cornell_spot", "--methods", "direct", "--no-progress"] + extra)
    assert cfg.reference_spp_cap == expected


@pytest.mark.parametrize("command", ["run", "sweep"])
def test_shadow_resolution_reaches_the_run_config(monkeypatch, command):
    """--shadow-resolution sets the shared shadow maps' tile side of `run` and `sweep`; unset, the
    runner sizes them from the image (RunConfig.shadow_resolution None)."""
    base = [command, "--scenes", "cornell_spot", "--methods", "direct", "--no-progress"]
    seen = [cli_run_config(monkeypatch, base + extra).shadow_resolution for extra in (["--shadow-resolution", "2048"], [])]
    assert seen == [2048, None]


@pytest.mark.parametrize("value", ["0", "9000", "big"])
def test_bad_shadow_resolution_is_one_line(capsys, value):
    with pytest.raises(SystemExit):
        main(["run", "--scenes", "cornell_spot", "--shadow-resolution", value])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "shadow resolution" in err and value in err


# ---------------------------------------------------------------------------- issue #27: one validation layer
class WorkStarted(Exception):
    """Raised by the stand-ins of the commands' work: a refused input must never reach them."""


@pytest.fixture
def no_work(monkeypatch, tmp_path):
    import bench.cli.stress
    import bench.run.cluster
    import bench.run.serial

    def started(*args, **kwargs):
        raise WorkStarted
    for owner, name in ((bench.run.serial, "run"), (bench.cli.stress, "run_stress"), (bench.run.cluster, "build_references")):
        monkeypatch.setattr(owner, name, started)
    monkeypatch.chdir(tmp_path)   # a default runs/ folder would appear here


BAD_OPTIONS = [
    (["run", "--scenes", ""], "--scenes"), (["run", "--scenes", "cornell_spot,"], "--scenes"),
    (["run", "--timing-budget", "-1"], "--timing-budget"), (["run", "--timing-budget", "nan"], "--timing-budget"),
    (["run", "--timing-budget", "inf"], "--timing-budget"), (["run", "--workers", "0"], "--workers"),
    (["run", "--workers", "-2"], "--workers"), (["run", "--reference-spp", "0"], "--reference-spp"),
    (["run", "--reference-spp", "1"], "--reference-spp"), (["run", "--frames", "0"], "--frames"),
    (["run", "--warmup", "0"], "--warmup"), (["run", "--seed", "-1"], "--seed"), (["run", "--res", "0x0"], "--res"),
    (["run", "--res", "32x99999"], "--res"), (["run", "--out", ""], "--out"), (["run", "--scheduler", " "], "--scheduler"),
    (["run", "--methods", "direct,direct"], "--methods"), (["run", "--methods", "direct/x"], "--methods"),
    (["run", "--views", "main,main"], "--views"), (["run", "--views", "a/../../b"], "--views"),
    (["run", "--param", "flc.n_avg=64,64"], "flc.n_avg"), (["run", "--param", "n_avg=3"], "--param"),
    (["sweep", "--scenes", ""], "--scenes"), (["sweep", "--frames", "-1"], "--frames"),
    (["stress", "--res", "0x0"], "--res"), (["stress", "--timeout", "-1"], "--timeout"),
    (["stress", "--timeout", "0"], "--timeout"), (["stress", "--fuzz-examples", "-1"], "--fuzz-examples"),
    (["stress", "--only", "scale,scale"], "--only"), (["stress", "--only", ""], "--only"),
    (["stress", "--seed", "-1"], "--seed"), (["stress", "--scenes", ""], "--scenes"),
    (["reference", "build", "--spp", "0"], "--spp"), (["reference", "build", "--workers", "0"], "--workers"),
    (["reference", "build", "--scenes", ""], "--scenes"), (["reference", "build", "--res", "4x4"], "--res"),
]


@pytest.mark.parametrize("argv, option", BAD_OPTIONS, ids=[" ".join(a) for a, _ in BAD_OPTIONS])
def test_bad_option_values_are_refused_before_any_work(argv, option, capsys, no_work, tmp_path):
    """Each was replaced (--scenes '' ran the whole corpus, --reference-spp 0 became 1024, stress --res 0x0
    became 64x48), accepted (--workers 0, stress --timeout -1) or a traceback: one line naming the option, exit 2."""
    with pytest.raises(SystemExit) as info:
        main(argv + (["--methods", "direct"] if argv[0] in ("run", "sweep", "stress") and "--methods" not in argv
                     else []))
    assert info.value.code == 2
    err = _one_line_err(capsys)
    assert option in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, message", [
    (["run", "--methods", "flc", "--param", "flc.n_avg=64", "--param", "flc.n_avg=128"],
     "--param flc.n_avg is given twice; give its values in one list"),
    (["run", "--methods", "flc", "--param", "flc.n_avg=64,64.0"], "the same parameters"),
    (["run", "--methods", "direct", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
    (["reference", "build", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "not both"),
])
def test_duplicates_and_conflicts_are_refused(argv, message, capsys, no_work, tmp_path):
    """Two sets of one row key wrote two rows; a repeated --param kept only the last; --scheduler
    silently won over --workers."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2 and message in _one_line_err(capsys)
    assert list(tmp_path.iterdir()) == []


def test_malformed_param_exits_2_not_1(capsys):
    with pytest.raises(SystemExit) as info:
        _param_sets(["flc.n_avg"])
    assert info.value.code == 2 and "--param expects METHOD.NAME=VALUE" in _one_line_err(capsys)


def test_a_plugin_name_unsafe_in_a_path_is_refused(monkeypatch, capsys, no_work):
    """A registered method's name becomes images/<scene>/<view>/<method>: a slash would leave the run folder."""
    from importlib.metadata import EntryPoint

    import bench.protocol.registry as registry
    evil = EntryPoint(name="evil/../../x", value="methods.direct.method:Direct", group=registry.GROUP)
    monkeypatch.setattr(registry, "_entry_points", lambda: {evil.name: evil})
    with pytest.raises(SystemExit) as info:
        main(["run", "--scenes", "cornell_spot", "--methods", "evil/../../x"])
    assert info.value.code == 2 and "method name 'evil/../../x' is not allowed" in _one_line_err(capsys)


def test_valid_edges_reach_the_run_config(monkeypatch, no_work):
    """The ends of the declared ranges are accepted and kept (0 s of budget: exactly --frames)."""
    import bench.run.serial
    seen = {}

    def fake_run(cfg, log=None, **kw):
        seen.update(cfg.__dict__)
        raise WorkStarted
    monkeypatch.setattr(bench.run.serial, "run", fake_run)
    with pytest.raises(WorkStarted):
        main(["run", "--scenes", " cornell_spot , rooms", "--methods", "direct", "--views", "main", "--res", "8x8192",
              "--timing-budget", "0", "--reference-spp", "2", "--seed", "0", "--workers", "256", "--no-progress"])
    assert seen["scenes"] == ["cornell_spot", "rooms"] and seen["views"] == ["main"]
    assert (seen["width"], seen["height"], seen["timing_budget_s"], seen["reference_spp_cap"], seen["workers"]) == \
        (8, 8192, None, 2, 256)


def test_camera_name_escaping_the_run_folder_is_refused(tmp_path, capsys, private_cache):
    (tmp_path / "q.obj").write_text("v 0 0 0\nv 1 0 0\nv 1 0 1\nf 1 2 3\n")
    (tmp_path / "s.toml").write_text('[[mesh]]\nfile = "q.obj"\n[[light]]\ntype = "point"\nposition = [0, 1, 0]\n'
                                     'intensity = 1\n[camera."a/../../../../escaped"]\neye = [0, 2, 2]\n'
                                     'target = [0, 0, 0]\n')
    assert main(["run", "--scenes", str(tmp_path / "s.toml"), "--methods", "direct", "--res", "16x12", "--frames", "1",
                 "--no-reference", "--no-progress", "--out", str(tmp_path / "r")]) == 2
    assert "camera name 'a/../../../../escaped' is not allowed" in _one_line_err(capsys)
    assert not (tmp_path / "escaped").exists()


@pytest.mark.parametrize("command", [["run"], ["sweep"], ["stress"], ["reference", "build"], ["list"], ["report"],
                                     ["gate"], ["manuals"]])
def test_every_help_renders(command, capsys):
    """Help strings carry the declared ranges (formatted by argparse: a stray % breaks --help)."""
    with pytest.raises(SystemExit) as info:
        main(command + ["--help"])
    out = capsys.readouterr().out
    assert info.value.code == 0 and "usage:" in out
    if command[0] in ("run", "sweep", "stress", "reference"):
        assert "(an integer in [" in " ".join(out.split()) and "W and H in [8, 8192]" in " ".join(out.split())
