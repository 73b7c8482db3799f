"""platkit import: the vendor exports of tests/data/importers (hand-made in each vendor's documented
layout by make_fixtures.py, not exported by the vendors' software) read against the truth they
were written from, sessions written from them loaded like any other, and bad files refused in one
line naming the file, line and column."""
from __future__ import annotations

import importlib.util
import shutil
from pathlib import Path

import numpy as np
import pytest

from platkit.cli import main
from platkit.errors import BadInput
from platkit.io.importers import read_recording, sniff
from platkit.io.session import load_session
from platkit.settle import load_poses

DATA = Path(__file__).resolve().parents[1] / "data" / "importers"
EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "sessions"
_spec = importlib.util.spec_from_file_location("make_fixtures", DATA / "make_fixtures.py")
truth = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(truth)

FILES = {"vicon_nexus.csv": "vicon", "qualisys_3d.tsv": "qualisys", "qualisys_6d.tsv": "qualisys",
         "motive.csv": "motive", "c3d_rigid.c3d": "c3d", "table_semicolon.csv": "table", "table_tab.tsv": "table"}


def read(name):
    return read_recording(DATA / name, unit="mm" if FILES[name] == "table" else None)


def same_rotation(q, ref):
    """Rows of q equal to ref up to sign (q and -q are one rotation)."""
    return np.minimum(np.abs(q - ref).max(axis=1), np.abs(q + ref).max(axis=1))


@pytest.mark.parametrize("name", sorted(FILES))
def test_each_export_is_recognised_and_read_as_written(name):
    assert sniff(DATA / name) == FILES[name]
    rec = read(name)
    assert rec.unit == "mm" and rec.n_samples == truth.N
    assert np.allclose(np.diff(rec.t), 1 / truth.RATE)
    tol = 2e-4 if name.endswith(".c3d") else 6e-4  # C3D stores float32; text 3 decimals
    has_markers = name != "qualisys_6d.tsv"
    has_body = name not in ("qualisys_3d.tsv",)
    if has_markers:
        assert sorted(rec.markers) == ["M1", "M2"]  # 'Stand:M1' -> 'M1'
        for m in ("M1", "M2"):
            seen = np.isfinite(rec.markers[m]).all(axis=1)
            assert np.abs(rec.markers[m][seen] - truth.M[m][seen]).max() < tol
        assert rec.occluded["M1"] == 0
        assert not np.isfinite(rec.markers["M2"][truth.GAP_M2]).any()
    if has_body:
        assert list(rec.bodies) == ["T"]
        pos, q = rec.bodies["T"]
        seen = np.isfinite(q).all(axis=1)
        assert seen.sum() == truth.N - 1 and not seen[truth.GAP_T] and rec.occluded["T"] == 1
        assert np.abs(pos[seen] - truth.POS[seen]).max() < tol
        assert same_rotation(q[seen], truth.Q[seen]).max() < 2e-5  # w,x,y,z, whatever the file's order


def test_gaps_written_as_zeros_are_occluded_and_counted():
    vicon, motive, qtm = read("vicon_nexus.csv"), read("motive.csv"), read("qualisys_3d.tsv")
    assert (vicon.occluded["M2"], vicon.zeros["M2"]) == (2, 1)  # an empty group and a 0,0,0 one
    assert (motive.occluded["M2"], motive.zeros["M2"]) == (2, 1)
    assert (qtm.occluded["M2"], qtm.zeros["M2"]) == (1, 1)
    assert "M2 2 (1 written as zeros)" in vicon.summary()


def test_what_is_left_out_is_said():
    assert any("'Devices'" in n for n in read("vicon_nexus.csv").notes)
    notes = read("motive.csv").notes
    assert any("Rigid Body Marker" in n for n in notes) and any("1 unlabelled" in n for n in notes)


def test_motive_quaternion_x_y_z_w_is_mapped_to_w_x_y_z():
    _, q = read("motive.csv").bodies["T"]
    k = 0
    assert np.allclose(q[k], truth.Q[k], atol=2e-6)  # read as w,x,y,z it would be another rotation
    assert not np.allclose(q[k], truth.Q[k][[1, 2, 3, 0]], atol=1e-2)


def test_the_cli_writes_a_session_the_loader_reads(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["import", str(DATA / "motive.csv"), "--out", str(out)]) == 0
    text = capsys.readouterr()
    assert "occluded samples: T 1, M2 2 (1 written as zeros)" in text.out
    assert "no commands.csv" in text.err
    lines = (out / "markers.csv").read_text().splitlines()
    assert lines[0] == "t,M1_x,M1_y,M1_z,M2_x,M2_y,M2_z,T_x,T_y,T_z,T_qw,T_qx,T_qy,T_qz"
    assert lines[1 + truth.GAP_T].endswith(",,,,,,,")
    # the written table read back by the plain reader: the same numbers
    back = read_recording(out / "markers.csv", unit="mm")
    rec = read("motive.csv")
    assert np.allclose(back.markers["M1"], rec.markers["M1"], atol=1e-4)
    assert np.allclose(back.bodies["T"][1], rec.bodies["T"][1], atol=1e-8, equal_nan=True)


def _as_vicon(folder: Path, path: Path) -> None:
    """A spec markers.csv (uniform rate) rewritten as a Vicon Nexus Trajectories export, frames from 1."""
    lines = (folder / "markers.csv").read_text().splitlines()
    names = [h[:-2] for h in lines[0].split(",")[1::3]]
    rate = 30.0
    rows = ["Trajectories", f"{rate:g}", ",," + ",".join(f"Sub:{n},," for n in names).rstrip(","),
            "Frame,Sub Frame," + ",".join(["X,Y,Z"] * len(names)), ",," + ",".join(["mm"] * 3 * len(names))]
    for line in lines[1:]:
        cells = line.split(",")
        rows.append(f"{round(float(cells[0]) * rate) + 1},0," + ",".join(cells[1:]))
    path.write_text("\n".join(rows) + "\n")


def test_a_real_session_through_a_vicon_export_reads_as_the_original(tmp_path):
    src = EXAMPLES / "rotary"
    export = tmp_path / "trial.csv"
    _as_vicon(src, export)
    out = tmp_path / "s"
    assert main(["import", str(export), "--out", str(out), "--platform", "rotary", "--commands",
                 str(src / "commands.csv"), "--time-offset-s", str(-1 / 30)]) == 0
    s, ref = load_session(out), load_session(src)  # the stream as the original's (its poses then follow)
    assert s.marker_names == ["M1", "M2", "M3", "M4", "M5"] and s.platform == "rotary"
    assert np.array_equal(s.marker_t, ref.marker_t) and np.array_equal(s.commands, ref.commands)
    assert np.array_equal(s.markers, ref.markers, equal_nan=True)


@pytest.mark.parametrize("edit, expected", [
    ("vicon_nexus.csv:15:1651.799:abc", "vicon_nexus.csv: line 15, column 3 (X): expected a number, got 'abc'"),
    ("motive.csv:1:Quaternion:XYZ", "motive.csv: line 1: Rotation Type is 'XYZ'"),
    ("motive.csv:8:0.988771:0.5", "motive.csv: line 8, rigid body 'T' (columns 3-6): the quaternion has norm"),
    ("motive.csv:1:Millimeters:Furlongs", "Length Units is 'Furlongs'"),
    ("qualisys_3d.tsv:1:NO_OF_FRAMES\t6:NO_OF_FRAMES\t9", "NO_OF_FRAMES says 9, the file has 6 data rows"),
    ("qualisys_6d.tsv:12:0.971415:1.971415", "line 12, body 'T': Rot[0..8] is not a rotation matrix"),
    ("table_semicolon.csv:3:1651,799:1651,7x9", "table_semicolon.csv: line 3, column 'M1_x': expected a number, got '1651,7x9'"),
])
def test_bad_files_are_one_line_naming_file_line_and_column(tmp_path, capsys, edit, expected):
    name, line, old, new = edit.split(":")
    path = tmp_path / name
    shutil.copy(DATA / name, path)
    lines = path.read_text().split("\n")
    assert old in lines[int(line) - 1], (old, lines[int(line) - 1])
    lines[int(line) - 1] = lines[int(line) - 1].replace(old, new, 1)
    path.write_text("\n".join(lines))
    args = ["import", str(path), "--out", str(tmp_path / "out")] + (["--unit", "mm"] if name.startswith("table") else [])
    assert main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and expected in err, err
    assert not (tmp_path / "out").exists()


def test_a_plain_table_needs_its_unit_and_a_comma_table_no_decimal_commas(tmp_path):
    with pytest.raises(BadInput, match="does not say its length unit"):
        read_recording(DATA / "table_semicolon.csv")
    p = tmp_path / "m.csv"
    p.write_text("t,M1_x,M1_y,M1_z\n0,1,5,2,3\n0.01,1,2,3\n")
    with pytest.raises(BadInput, match="line 2: 5 cells, expected 4 like the header"):
        read_recording(p, unit="mm")
    with pytest.raises(BadInput, match="the file says its lengths are in mm, --unit says m"):
        read_recording(DATA / "motive.csv", unit="m")


def _as_motive(folder: Path, path: Path, rate: float) -> None:
    """A spec markers.csv (markers and bodies, uniform rate) rewritten as a Motive CSV export:
    bodies' quaternions x,y,z,w then positions, markers after them, lengths in millimetres."""
    lines = (folder / "markers.csv").read_text().splitlines()
    header = lines[0].split(",")
    bodies = [h[:-3] for h in header if h.endswith("_qw")]
    markers = [h[:-2] for h in header[1:] if h.endswith("_x") and h[:-2] not in bodies]
    col = {h: k for k, h in enumerate(header)}
    order = []
    types, names, cats, comps = [], [], [], []
    for b in bodies:
        order += [f"{b}_{c}" for c in ("qx", "qy", "qz", "qw", "x", "y", "z")]
        types += ["Rigid Body"] * 7
        names += [b] * 7
        cats += ["Rotation"] * 4 + ["Position"] * 3
        comps += list("XYZW") + list("XYZ")
    for m in markers:
        order += [f"{m}_{c}" for c in "xyz"]
        types += ["Marker"] * 3
        names += [f"Stand:{m}"] * 3
        cats += ["Position"] * 3
        comps += list("XYZ")
    rows = [f"Format Version,1.23,Take Name,t,Export Frame Rate,{rate:.6f},Rotation Type,Quaternion,"
            "Length Units,Millimeters,Coordinate Space,Global", "",
            ",Type," + ",".join(types), ",Name," + ",".join(names), ",ID," + ",".join("1" * len(types)),
            ",," + ",".join(cats), "Frame,Time (Seconds)," + ",".join(comps)]
    for k, line in enumerate(lines[1:]):
        cells = line.split(",")
        rows.append(f"{k},{cells[0]}," + ",".join(cells[col[c]] for c in order))
    path.write_text("\r\n".join(rows) + "\r\n")


def _on_frame_times(src: Path, dst: Path) -> Path:
    """A copy of session ``src`` whose marker times are exactly what a Vicon export of it gives
    back (frame / 30 - 1 / 30: the example's times are written to 6 decimals, and a window edge
    may move with the last bit)."""
    dst.mkdir()
    for f in ("session.yaml", "commands.csv"):
        shutil.copy(src / f, dst)
    lines = (src / "markers.csv").read_text().splitlines()
    out = [lines[0]] + [repr((round(float(x.split(",", 1)[0]) * 30) + 1) / 30 + (-1 / 30)) + "," + x.split(",", 1)[1]
                        for x in lines[1:]]
    (dst / "markers.csv").write_text("\n".join(out) + "\n")
    return dst


def test_a_session_folder_holding_an_export_is_read_by_content(tmp_path):
    # the rotary example with its stream as a Vicon export, named by markers_file
    src = _on_frame_times(EXAMPLES / "rotary", tmp_path / "ref")
    folder = tmp_path / "vicon"
    folder.mkdir()
    shutil.copy(src / "commands.csv", folder)
    _as_vicon(src, folder / "trial.csv")
    (folder / "session.yaml").write_text((src / "session.yaml").read_text()
                                         + f"markers_file: trial.csv\nmarkers_time_offset: {-1 / 30!r}\n")
    s = load_session(folder)
    assert s.markers_source == folder / "trial.csv"
    assert any("Vicon CSV" in n for n in s.extras["control_notes"])
    a, b = load_poses(src), load_poses(folder)
    assert a.n_poses == b.n_poses and np.allclose(a.markers, b.markers, atol=1e-9, equal_nan=True)


def test_rigid_bodies_through_a_motive_export_and_a_c3d_file_keep_their_rotations(tmp_path):
    # a simulated session with a rigid body; its stream as a Motive export (quaternions x,y,z,w)
    src = tmp_path / "sim"
    assert main(["simulate", "--platform", "rotary", "--out", str(src), "--seed", "3", "--poses", "6",
                 "--rigid-bodies", "1", "--rate-hz", "50"]) == 0
    folder = tmp_path / "motive"
    folder.mkdir()
    shutil.copy(src / "commands.csv", folder)
    _as_motive(src, folder / "take.csv", 50.0)
    (folder / "session.yaml").write_text((src / "session.yaml").read_text() + "markers_file: take.csv\n")
    a, b = load_poses(src), load_poses(folder)
    assert a.n_poses == b.n_poses
    assert np.allclose(a.markers, b.markers, atol=1e-9, equal_nan=True)
    qa, qb = a.bodies[..., 3:], b.bodies[..., 3:]
    assert np.abs(np.abs(np.sum(qa * qb, axis=-1)) - 1).max() < 1e-12  # the same rotations
    assert np.allclose(a.bodies[..., :3], b.bodies[..., :3], atol=1e-9)
    # the same stream as a C3D file: points, and the body as a ROTATION group's 4x4 transforms
    c3d = tmp_path / "c3d"
    c3d.mkdir()
    shutil.copy(src / "commands.csv", c3d)
    _as_c3d(src, c3d / "take.c3d", 50.0)
    (c3d / "session.yaml").write_text((src / "session.yaml").read_text() + "markers_file: take.c3d\n")
    c = load_poses(c3d)
    assert c.n_poses == a.n_poses
    assert np.nanmax(np.abs(c.markers - a.markers)) < 1e-6  # float32 in the file: 0.1 um at metres
    assert np.abs(np.abs(np.sum(qa * c.bodies[..., 3:], axis=-1)) - 1).max() < 1e-10
    assert np.abs(c.bodies[..., :3] - a.bodies[..., :3]).max() < 1e-6


def _as_c3d(folder: Path, path: Path, rate: float) -> None:
    """A spec markers.csv (mm, uniform rate from t = 0) rewritten as a C3D file: its markers as
    points (occluded: residual -1), its bodies as ROTATION transforms (occluded: NaN)."""
    import ezc3d

    from platkit.geometry import matrix_from_quat

    lines = (folder / "markers.csv").read_text().splitlines()
    header = lines[0].split(",")
    data = np.array([[float(c) if c else np.nan for c in x.split(",")] for x in lines[1:]])
    col = {h: k for k, h in enumerate(header)}
    bodies = [h[:-3] for h in header if h.endswith("_qw")]
    markers = [h[:-2] for h in header[1:] if h.endswith("_x") and h[:-2] not in bodies]
    n = len(data)
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(markers)
    pts = np.ones((4, len(markers), n))
    res = np.zeros((1, len(markers), n))
    for j, m in enumerate(markers):
        xyz = data[:, [col[f"{m}_{a}"] for a in "xyz"]]
        gone = ~np.isfinite(xyz).all(axis=1)
        pts[:3, j] = np.where(gone[:, None], 0.0, xyz).T
        res[0, j, gone] = -1.0
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = res
    c.add_parameter("POINT", "UNITS", "mm")
    rot = np.full((4, 4, len(bodies), n), np.nan)
    for j, b in enumerate(bodies):
        q = data[:, [col[f"{b}_{a}"] for a in ("qw", "qx", "qy", "qz")]]
        seen = np.isfinite(q).all(axis=1)
        T = np.zeros((int(seen.sum()), 4, 4))
        T[:, :3, :3] = matrix_from_quat(q[seen] / np.linalg.norm(q[seen], axis=1, keepdims=True))
        T[:, :3, 3] = data[seen][:, [col[f"{b}_{a}"] for a in "xyz"]]
        T[:, 3, 3] = 1.0
        rot[:, :, j, seen] = T.transpose(1, 2, 0)
    c["data"]["rotations"] = rot
    c.add_parameter("ROTATION", "LABELS", tuple(bodies))
    c.write(str(path))


def test_a_declared_marker_the_export_lacks_is_one_line(tmp_path):
    folder = tmp_path / "s"
    folder.mkdir()
    shutil.copy(EXAMPLES / "rotary" / "commands.csv", folder)
    shutil.copy(DATA / "vicon_nexus.csv", folder)
    (folder / "session.yaml").write_text((EXAMPLES / "rotary" / "session.yaml").read_text()
                                         + "markers_file: vicon_nexus.csv\n")
    with pytest.raises(BadInput, match=r"vicon_nexus.csv: no marker 'M3' \(declared in .*session.yaml\); the export has M1, M2"):
        load_session(folder)


@pytest.mark.parametrize("sep", [";", "\t"])
def test_a_session_table_with_another_separator_and_decimal_commas_reads_the_same(tmp_path, sep):
    from platkit.io.table import read_table

    src = EXAMPLES / "rotary"
    folder = tmp_path / "s"
    shutil.copytree(src, folder)
    for name in ("markers.csv", "commands.csv"):
        text = (src / name).read_text()
        (folder / name).write_text(text.replace(",", sep).replace(".", ","))
    for name in ("markers.csv", "commands.csv"):
        a, b = read_table(src / name), read_table(folder / name)
        assert a.header == b.header and np.array_equal(a.data, b.data, equal_nan=True)
    lines = (folder / "markers.csv").read_text().splitlines()
    lines[2] = lines[2].replace(",", ",x", 1)  # row 2, column t: '0,x033333'
    (folder / "markers.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInput, match=r"markers.csv row 2 \(line 3\) column 't': expected a number, got '0,x033333'"):
        read_table(folder / "markers.csv")


def test_layout_variants_read_the_same(tmp_path):
    ref = read("qualisys_3d.tsv")
    # QTM on a decimal-comma locale; and an older export without the Frame/Time row
    lines = (DATA / "qualisys_3d.tsv").read_text().splitlines()
    comma = tmp_path / "comma.tsv"
    comma.write_text("\n".join(lines[:12] + [x.replace(".", ",") for x in lines[12:]]) + "\n")
    old = tmp_path / "old.tsv"
    old.write_text("\n".join(lines[:11] + ["\t".join(x.split("\t")[2:]) for x in lines[12:]]) + "\n")
    for path in (comma, old):
        rec = read_recording(path)
        assert np.array_equal(rec.markers["M1"], ref.markers["M1"]) and np.allclose(rec.t, ref.t)
    # a Vicon export whose rows end with a comma
    vicon = tmp_path / "v.csv"
    vicon.write_text("\n".join(x + "," if x and x[0] in ",F0123456789" else x
                               for x in (DATA / "vicon_nexus.csv").read_text().splitlines()) + "\n")
    rec, ref = read_recording(vicon), read("vicon_nexus.csv")
    assert np.array_equal(rec.markers["M2"], ref.markers["M2"], equal_nan=True)
    assert np.array_equal(rec.bodies["T"][1], ref.bodies["T"][1], equal_nan=True)


def test_a_vendor_export_saved_as_markers_csv_is_read_by_its_content(tmp_path):
    folder = tmp_path / "s"
    folder.mkdir()
    shutil.copy(EXAMPLES / "rotary" / "commands.csv", folder)
    _as_vicon(EXAMPLES / "rotary", folder / "markers.csv")
    (folder / "session.yaml").write_text((EXAMPLES / "rotary" / "session.yaml").read_text())
    s = load_session(folder)
    assert any(n.startswith(f"{folder / 'markers.csv'}: Vicon CSV, 2085 samples") for n in s.extras["control_notes"])
    assert np.array_equal(s.markers, load_session(EXAMPLES / "rotary").markers, equal_nan=True)


def test_vicon_section_names_in_capitals_and_the_older_layout_refused(tmp_path, capsys):
    # section names in capitals read as the same export
    caps = tmp_path / "caps.csv"
    caps.write_text("\n".join(x.upper() if x.strip() in ("Trajectories", "Segments", "Devices") else x
                              for x in (DATA / "vicon_nexus.csv").read_text().splitlines()) + "\n")
    assert "TRAJECTORIES" in caps.read_text() and sniff(caps) == "vicon"
    rec, ref = read_recording(caps), read("vicon_nexus.csv")
    assert np.array_equal(rec.markers["M2"], ref.markers["M2"], equal_nan=True) and list(rec.bodies) == ["T"]
    # the older layout (the one pyCGM 1.0's loadCSV reads: a 'Field #' column, no Sub Frame, no
    # units row; hand-made here, no such export was found): refused in one line, nothing written
    old = tmp_path / "old.csv"
    old.write_text("TRAJECTORIES\n100\n,Stand:M1,,,Stand:M2,,\nField #,X,Y,Z,X,Y,Z\n"
                   "1,1650.5,864.2,3553.6,1700.0,800.0,3500.0\n2,1650.6,864.3,3553.7,1700.1,800.1,3500.1\n")
    assert main(["import", str(old), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "old.csv: line 4: an older Vicon CSV layout" in err, err
    assert "does not say its length unit" in err and not (tmp_path / "out").exists()


def test_a_c3d_transform_stored_transposed_is_refused_not_read_as_a_body_at_the_origin(tmp_path, capsys):
    import ezc3d

    c = ezc3d.c3d(str(DATA / "c3d_rigid.c3d"))
    rot = np.asarray(c["data"]["rotations"], float)
    assert np.abs(rot[:3, 3, 0, 0]).max() > 100  # the fixture's translation, where the reader takes it
    new = ezc3d.c3d()
    for group, name in (("POINT", "RATE"), ("POINT", "LABELS")):
        new["parameters"][group][name]["value"] = c["parameters"][group][name]["value"]
    new["data"]["points"] = np.asarray(c["data"]["points"], float)
    new.add_parameter("POINT", "UNITS", "mm")
    new["data"]["rotations"] = rot.transpose(1, 0, 2, 3)  # the translation in the bottom row
    new.add_parameter("ROTATION", "LABELS", ("Stand:T",))
    path = tmp_path / "transposed.c3d"
    new.write(str(path))
    assert main(["import", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "transposed.c3d: rotation 'Stand:T', frame 0: the 4x4 transform's bottom row is" in err, err
    assert "its translation is in the bottom row: the matrix is stored transposed" in err and not (tmp_path / "out").exists()
