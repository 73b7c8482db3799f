"""The kinematics verbs of the CLI: JSON output, exit codes, one-line errors, workspace files."""
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from platkit.cli import main

STEWART_YAML = Path(__file__).resolve().parents[2] / "descriptions" / "stewart.yaml"


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, f"expected one line on stderr, got {err!r}"
    assert lines[0].startswith("platkit: error: ")
    assert "Traceback" not in err
    return lines[0]


@pytest.mark.parametrize("argv", [
    ["plugins", "--json"],
    ["describe", "--platform", "stewart", "--json"],
    ["fk", "--platform", "stewart", "--u", "3300,3581,4158,4521,3854,4029", "--json"],
    ["ik", "--platform", "stewart", "--pose", "100,-50,3200,0.05,-0.02,0.1", "--json"],
])
def test_json_verbs_print_one_object(capsys, argv):
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    obj = json.loads(out)  # the whole of stdout is one JSON document
    assert isinstance(obj, dict)


def test_fk_json_fields(capsys):
    code, out, _ = run(capsys, "fk", "--platform", "stewart", "--u", "3300,3581,4158,4521,3854,4029", "--json")
    obj = json.loads(out)
    assert obj["unit"] == "mm" and obj["iterations"] <= 5 and obj["on_branch"] is True
    assert {"x", "y", "z", "qw", "qx", "qy", "qz", "roll", "pitch", "yaw"} <= set(obj)
    np.testing.assert_allclose([obj["x"], obj["y"], obj["z"]], [539.2116, -292.3542, 2901.6304], atol=1e-3)


def test_ik_then_fk_through_the_cli(capsys):
    code, out, _ = run(capsys, "ik", "--platform", "stewart", "--pose", "100,-50,3200,0.05,-0.02,0.1", "--json")
    legs = json.loads(out)["controls"]
    u = ",".join(f"{legs[f'L{i}']:.9f}" for i in range(1, 7))
    code, out, _ = run(capsys, "fk", "--platform", "stewart", "--u", u, "--json")
    obj = json.loads(out)
    np.testing.assert_allclose([obj["x"], obj["y"], obj["z"], obj["roll"], obj["pitch"], obj["yaw"]],
                               [100, -50, 3200, 0.05, -0.02, 0.1], atol=1e-6)


def test_describe_lists_42_parameters(capsys):
    code, out, _ = run(capsys, "describe", "--platform", "stewart", "--json")
    obj = json.loads(out)
    assert obj["n_parameters"] == 42 and len(obj["controls"]) == 6
    assert obj["controls"][0]["unit"] == "mm" and obj["controls"][0]["upper"] == pytest.approx(4795)


@pytest.mark.parametrize("argv, code, text", [
    (["fk", "--platform", "stewart", "--u", "4000,4000,4000,4000,4000"], 2, "--u: expected 6 numbers, got 5"),
    (["fk", "--platform", "stewart", "--u", "4000,4000,x,4000,4000,4000"], 2, "expected comma-separated numbers"),
    (["fk", "--platform", "stewart", "--u", "4900,4000,4000,4000,4000,4000"], 1,
     "control L1: 4900 is outside the stroke [3295, 4795] mm: 105 mm past the limit 4795"),
    (["fk", "--platform", "stewart", "--unit", "m", "--u", "4.9,4,4,4,4,4"], 1,
     "control L1: 4.9 is outside the stroke [3.295, 4.795] m: 0.105 m past the limit 4.795"),
    (["fk", "--platform", "stewart", "--u", "3300,3581,4158,4521,3854,4029", "--guess", "0,0,-3000,0,0,0"], 1,
     "mirror pose the stand cannot take: origin at (539.2, -292.4, -2901.6) mm"),
    (["ik", "--platform", "stewart", "--pose", "0,0,6000,0,0,0"], 1,
     "the pose at (0.0, 0.0, 6000.0) mm is out of reach: control L1 would be 6515.96 mm"),
    (["ik", "--platform", "stewart", "--pose", "0,0,3147,0,0"], 2, "--pose: expected 6"),
    (["fk", "--platform", "nosuch", "--u", "1"], 2, "unknown platform 'nosuch'; installed stands:"),
])
def test_bad_input_and_failures_are_one_line(capsys, argv, code, text):
    got, out, err = run(capsys, *argv)
    line = one_line_error(err)
    assert got == code, line
    assert text in line, line
    assert out == ""


def _description(tmp_path, edit, name="bad.yaml"):
    data = yaml.safe_load(STEWART_YAML.read_text())
    edit(data)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _del(d, *keys):
    for k in keys[:-1]:
        d = d[k]
    del d[keys[-1]]


@pytest.mark.parametrize("edit, text", [
    (lambda d: _del(d, "neutral_pose"), "missing field 'neutral_pose'"),
    (lambda d: _del(d, "units", "length"), "missing field 'units.length'"),
    (lambda d: d["units"].update(length="inch"), "field 'units.length' must be 'mm' or 'm', got 'inch'"),
    (lambda d: d["legs"][0].update(stroke="long"), "field 'legs[0].stroke' must be list, got str"),
    (lambda d: d["legs"][2].update(base_joint=[1, 2]), "field 'legs[2].base_joint' must be a list of 3 numbers"),
    (lambda d: d.update(legs=d["legs"][:5]), "field 'legs' must list 6 legs, got 5"),
    (lambda d: d["legs"][0].update(stroke=[4795, 3295]), "legs[0].stroke must be [min, max] with min < max"),
    (lambda d: d["neutral_pose"].update(position=[0, 0, 1000]), "leg L1 is 2730.88 mm long at the neutral pose"),
    (lambda d: d["legs"][1].update(base_joint=d["legs"][0]["base_joint"], platform_joint=d["legs"][0]["platform_joint"]),
     "legs L1 and L2 have the same base and platform joints"),
])
def test_malformed_description_is_bad_input(capsys, tmp_path, edit, text):
    path = _description(tmp_path, edit)
    code, out, err = run(capsys, "fk", "--platform", "stewart", "--description", str(path),
                         "--u", "4000,4000,4000,4000,4000,4000")
    line = one_line_error(err)
    assert code == 2, line
    assert str(path) in line and text in line, line


def test_description_that_is_not_yaml(capsys, tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("platform: stewart\nunits: {length: mm\nlegs: [\n")
    code, _, err = run(capsys, "describe", "--platform", "stewart", "--description", str(path))
    line = one_line_error(err)
    assert code == 2 and "broken.yaml: line 3 is not valid YAML" in line


def test_workspace_writes_figures_and_plots(capsys, tmp_path):
    out = tmp_path / "ws"
    code, stdout, err = run(capsys, "workspace", "--platform", "stewart", "--out", str(out), "--json")
    assert code == 0, err
    obj = json.loads(stdout)
    assert sorted(p.name for p in out.iterdir()) == ["coordinates.csv", "corners.csv", "envelope.csv", "sections.png",
                                                    "workspace.json", "workspace.png"]
    saved = json.loads((out / "workspace.json").read_text())
    assert saved == obj
    rel = saved["corners"]["relative_to_neutral"]
    assert abs(rel["x"]["min"] + 1493) < 1 and abs(rel["z"]["max"] - 919) < 1
    assert saved["corners"]["count"] == 64 and saved["unit"] == "mm"
    fixed = saved["true_envelope"]["fixed_orientation"]
    assert fixed["y"]["range_ratio_to_corners"] < 0.9  # at the neutral orientation the reach in y is smaller
    assert len((out / "corners.csv").read_text().splitlines()) == 65
    coordinates = saved["coordinates"]  # the six pose coordinates' ranges, x within the free envelope's
    assert list(coordinates) == ["x", "y", "z", "roll", "pitch", "yaw"] and coordinates["yaw"]["unit"] == "rad"
    assert abs(coordinates["x"]["min"] - (saved["neutral_position"][0] + saved["true_envelope"]["free_orientation"]["x"]["min"])) < 0.1


def test_workspace_failure_writes_nothing(capsys, tmp_path):
    bad = _description(tmp_path, lambda d: _del(d, "legs"))
    out = tmp_path / "ws"
    code, _, err = run(capsys, "workspace", "--platform", "stewart", "--description", str(bad), "--out", str(out))
    assert code == 2 and "missing field 'legs'" in one_line_error(err)
    assert not out.exists() or not any(out.iterdir())


# ----------------------------------------------------------------------------- start-up (issue 13)


def test_a_verb_imports_only_its_own_module():
    """`platkit fk` builds the parser of fk alone: no other verb's module (and none of the
    heavy libraries they pull in) is imported; `--version` imports no verb and no CasADi."""
    import subprocess
    import sys

    probe = (
        "import sys; from platkit.cli import main; code = main(sys.argv[1:]); "
        "print(sorted(m for m in sys.modules if m.startswith('platkit.commands.') and m != 'platkit.commands.common'), "
        "'casadi' in sys.modules, 'scipy.stats' in sys.modules, code)"
    )
    fk = subprocess.run([sys.executable, "-c", probe, "fk", "--platform", "stewart", "--u", "4000,4000,4000,4000,4000,4000"],
                        capture_output=True, text=True, check=True)
    assert fk.stdout.strip().splitlines()[-1] == "['platkit.commands.fk'] True False 0"
    version = subprocess.run([sys.executable, "-c", probe, "--version"], capture_output=True, text=True, check=True)
    assert version.stdout.strip().splitlines() == ["platkit 0.1.0", "[] False False 0"]


def test_help_lists_every_verb(capsys):
    from platkit.cli import COMMANDS

    code, out, _ = run(capsys, "--help")
    assert code == 0
    for name in COMMANDS:
        assert f"    {name}" in out


def test_an_unknown_verb_is_bad_input_naming_the_verbs(capsys):
    code, _, err = run(capsys, "fx", "--platform", "stewart")
    assert code == 2
    assert "invalid choice: 'fx'" in err and "'fk'" in err and "'simulate'" in err


def test_ctrl_c_while_a_verb_loads_is_one_line_and_130(capsys, monkeypatch):
    import platkit.cli as cli

    def interrupted(name):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli.importlib, "import_module", interrupted)
    code, out, err = run(capsys, "fk", "--platform", "stewart", "--u", "4000,4000,4000,4000,4000,4000")
    assert code == 130 and out == "" and err == "platkit: interrupted\n"


def test_ctrl_c_during_a_run_is_one_line_and_130(capsys, monkeypatch):
    import platkit.commands.fk as fk

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(fk, "run", interrupted)
    code, out, err = run(capsys, "fk", "--platform", "stewart", "--u", "4000,4000,4000,4000,4000,4000")
    assert code == 130 and err == "platkit: interrupted\n"


def test_parsers_keep_the_library_lists_they_copy():
    """Verbs whose parser would otherwise import a heavy module keep a copy of its choices."""
    import platkit.commands.orient as orient_command
    import platkit.inertial.orient as orient_library

    assert orient_command.METHODS == orient_library.METHODS


def test_simulate_parser_imports_no_simulator_until_help_is_shown(capsys):
    """Building `platkit simulate`'s parser reads no effect docstrings (that imports the
    simulator and scipy.stats); `platkit simulate --help` still lists every effect's size."""
    import subprocess
    import sys

    probe = ("import sys, argparse; import platkit.commands.simulate as m; p = argparse.ArgumentParser(); "
             "m.add_parser(p.add_subparsers()); print('platkit.simulate' in sys.modules, 'scipy.stats' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["False", "False"]
    code, out, _ = run(capsys, "simulate", "--help")
    assert code == 0 and "Sizes: backlash:" in " ".join(out.split())
