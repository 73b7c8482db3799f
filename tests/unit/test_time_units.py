"""Time units checked against mocap_rate_hz and the command log: times in ms declared as s (and the
reverse), a mocap_rate_hz the stream contradicts, a command log and a stream in different units:
refused in one line naming the file and field, and answerable (--units-checked)."""
from __future__ import annotations

import shutil

import pytest

from platkit.cli import main
from platkit.errors import BadSession
from platkit.io.session import example_session, load_session
from platkit.notices import units_checked


def _copy(tmp_path, scale_markers=1.0, scale_commands=1.0, yaml_edit=None):
    folder = tmp_path / "s"
    shutil.copytree(example_session("stewart"), folder)
    for name, k in (("markers.csv", scale_markers), ("commands.csv", scale_commands)):
        if k != 1.0:
            lines = (folder / name).read_text().splitlines()
            out = [lines[0]] + [",".join([f"{float(r.split(',', 1)[0]) * k:.6f}", r.split(",", 1)[1]])
                                for r in lines[1:]]
            (folder / name).write_text("\n".join(out) + "\n")
    if yaml_edit:
        y = (folder / "session.yaml").read_text()
        for a, b in yaml_edit:
            assert a in y
            y = y.replace(a, b)
        (folder / "session.yaml").write_text(y)
    return folder


def test_the_example_reads(tmp_path):
    load_session(_copy(tmp_path))


def test_milliseconds_declared_as_seconds(tmp_path, capsys):
    folder = _copy(tmp_path, 1000.0, 1000.0)
    out = tmp_path / "o"
    assert main(["calibrate", str(folder), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and not out.exists()
    assert err.startswith(f"platkit: error: {folder / 'markers.csv'}: column 't': the median time step is 25 s "
                          "(0.04 Hz), but session.yaml's field 'mocap_rate_hz' declares 40 Hz (units: time: s); the "
                          "times look like milliseconds")
    assert err.endswith("run again with --units-checked")


def test_seconds_declared_as_milliseconds(tmp_path):
    folder = _copy(tmp_path, yaml_edit=[("time: s", "time: ms")])
    with pytest.raises(BadSession, match=r"markers.csv: column 't': the median time step is 2\.5e-05 s \(4e\+04 Hz\), "
                                         r"but session.yaml's field 'mocap_rate_hz' declares 40 Hz \(units: time: ms\); "
                                         r"the times look like seconds in a session declared in milliseconds"):
        load_session(folder)


def test_a_mocap_rate_the_stream_contradicts(tmp_path):
    folder = _copy(tmp_path, yaml_edit=[("mocap_rate_hz: 40.0", "mocap_rate_hz: 200.0")])
    with pytest.raises(BadSession, match=r"column 't': the median time step is 0\.025 s \(40 Hz\), but session.yaml's "
                                         r"field 'mocap_rate_hz' declares 200 Hz \(units: time: s\); correct "
                                         r"mocap_rate_hz or the times"):
        load_session(folder)
    with units_checked():  # answered: kept, with the sentence as a warning
        with pytest.warns(UserWarning, match="declares 200 Hz.*kept as written: --units-checked"):
            load_session(folder)


def test_without_a_declared_rate_a_stream_no_mocap_records(tmp_path):
    folder = _copy(tmp_path, 1000.0, 1000.0, yaml_edit=[("mocap_rate_hz: 40.0", "mocap_rate_hz: null")])
    with pytest.raises(BadSession, match=r"0\.04 Hz\), slower than a motion-capture system records .*the times look "
                                         r"like milliseconds"):
        load_session(folder)


def test_a_command_log_in_another_unit_than_the_stream(tmp_path):
    folder = _copy(tmp_path, scale_commands=1000.0)
    with pytest.raises(BadSession, match=r"commands.csv: column 't' spans .* s, markers.csv's .* s \(986 times as "
                                         r"long\): the two files' times are not in the same unit"):
        load_session(folder)
