"""Bad inputs, as users have them, through every verb of the command line: each case's outcome
classed precise / vague / silent-wrong / traceback (goal: 0 silent wrong answers, 0 tracebacks).

Each case is one command line (run in-process through ``platkit.cli.main``) on inputs made from
the shipped example sessions (stewart, rotary), from the real TIAGo recordings in
``../shared/data/real/tiago`` (converted as tests/real_data/tiago.py converts them), from the
importers' small export files in tests/data/importers, and from sessions ``platkit simulate``
writes (rigid bodies, an IMU), with one thing wrong: malformed CSV, YAML and URDF, wrong units
(ms as s, m as mm, deg as rad), quaternions in x,y,z,w order, missing columns, NaN and inf,
duplicated or decreasing times, empty files, a wrong stand, links and joints not in the URDF, a
mimic joint's master missing, negative masses, values just past a limit (within the recording
tolerance: the same warning in every verb) or further, clocks that do not overlap, a command log
sparser than the motion.

Each case states what it expects, any one of:
- ``error(code, *names)``: exit ``code`` (2 bad input, 1 failed computation; ../shared/spec 4)
  with exactly one ``platkit: error:`` line holding every one of ``names`` (the file, field,
  row, option it must name);
- ``warning(*names)``: exit 0 and a warning holding ``names`` in the verb's written outputs
  (report.json's ``warnings`` for calibrate and orient, diagnosis.json's for diagnose, plan.json's
  for plan, session.yaml's notes for simulate and import, task.json's for batch, the
  ``--json`` object for track and fk); verbs that write no report (predict, ik) say it on stderr;
- ``accepted()``: exit 0 and a result that agrees with the truth where the case can check it.

Classes:
- precise: the outcome is one the case expects;
- vague: a refusal or warning, but not the expected one (another exit code, more than one line,
  a name missing, a warning on stderr only, a refusal of data that should be kept);
- SILENT-WRONG: exit 0 with no warning where one was expected, or a result that does not agree;
- TRACEBACK: an unexpected exception (the "run with --debug for the traceback" line).

Run:  .venv/bin/python benchmarks/bad_inputs_sweep.py [--verbs calibrate,predict,...] [--only SUBSTRING]
      [--list] [--show vague,SILENT-WRONG,TRACEBACK]
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import shutil
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from platkit.calibrate.predict import prediction_table, read_commands  # noqa: E402
from platkit.cli import main  # noqa: E402
from platkit.io.calibration import read_calibration  # noqa: E402
from platkit.io.session import example_session  # noqa: E402
from platkit.model import length_scale  # noqa: E402
from platkit.notices import PlatkitWarning  # noqa: E402

VERBS = ("calibrate", "predict", "diagnose", "fk", "ik", "simulate", "plan", "track", "orient", "import", "batch")
CLASSES = ("precise", "vague", "SILENT-WRONG", "TRACEBACK")
TIAGO = ROOT.parent / "shared" / "data" / "real" / "tiago"
IMPORTERS = ROOT / "tests" / "data" / "importers"
BROAD = ROOT.parent / "shared" / "data" / "real" / "broad"
#: a real BROAD trial (Laidig et al. 2021) with an opening rest
BROAD_TRIAL = "24_disturbed_tapping_A.hdf5"


# ------------------------------------------------------------------ what a case expects
@dataclass(frozen=True)
class Expect:
    kind: str  # "error" | "warning" | "accepted"
    code: int = 0
    names: tuple[str, ...] = ()


def error(code: int, *names: str) -> Expect:
    return Expect("error", code, names)


def warning(*names: str) -> Expect:
    return Expect("warning", 0, names)


def accepted() -> Expect:
    return Expect("accepted")


@dataclass
class Case:
    verb: str
    name: str
    #: (work folder, fixtures) -> the command line; makes the case's inputs in the work folder
    make: Callable[[Path, Fixtures], list[str]]
    expect: tuple[Expect, ...]
    #: (work folder, fixtures, stdout) -> the warnings the verb wrote into its outputs
    outputs: Callable[[Path, Fixtures, str], list[str]] | None = None
    #: (work folder, fixtures, stdout) -> whether the result agrees with the truth (None: not checked)
    check: Callable[[Path, Fixtures, str], bool | None] | None = None


@dataclass
class Result:
    case: Case
    rc: int
    klass: str
    why: str
    err: str
    seconds: float


# ------------------------------------------------------------------ editing files
def rows_of(path: Path, sep: str = ",") -> list[list[str]]:
    with path.open(newline="") as fh:
        return list(csv.reader(fh, delimiter=sep))


def write_rows(path: Path, rows: list[list[str]]) -> None:
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def scale_column(path: Path, col: str, k: float) -> None:
    rows = rows_of(path)
    j = rows[0].index(col)
    for r in rows[1:]:
        if r[j]:
            r[j] = f"{float(r[j]) * k:.12g}"
    write_rows(path, rows)


def scale_columns(path: Path, cols: list[str], k: float) -> None:
    for c in cols:
        scale_column(path, c, k)


def scale_suffix(path: Path, suffixes: tuple[str, ...], k: float) -> None:
    rows = rows_of(path)
    scale_columns(path, [h for h in rows[0] if h.endswith(suffixes)], k)


def shift_column(path: Path, col: str, d: float) -> None:
    rows = rows_of(path)
    j = rows[0].index(col)
    for r in rows[1:]:
        if r[j]:
            r[j] = f"{float(r[j]) + d:.9f}"
    write_rows(path, rows)


def edit_cell(path: Path, row: int, col: str, value: str) -> None:
    rows = rows_of(path)
    rows[row][rows[0].index(col)] = value
    write_rows(path, rows)


def rename_column(path: Path, old: str, new: str) -> None:
    rows = rows_of(path)
    rows[0][rows[0].index(old)] = new
    write_rows(path, rows)


def drop_column(path: Path, col: str) -> None:
    rows = rows_of(path)
    j = rows[0].index(col)
    write_rows(path, [r[:j] + r[j + 1:] for r in rows])


def drop_columns_like(path: Path, prefix: str) -> None:
    rows = rows_of(path)
    keep = [j for j, h in enumerate(rows[0]) if not h.startswith(prefix)]
    write_rows(path, [[r[j] for j in keep] for r in rows])


def swap_headers(path: Path, a: str, b: str) -> None:
    rows = rows_of(path)
    i, j = rows[0].index(a), rows[0].index(b)
    rows[0][i], rows[0][j] = b, a
    write_rows(path, rows)


def swap_rows(path: Path, i: int, j: int) -> None:
    rows = rows_of(path)
    rows[i], rows[j] = rows[j], rows[i]
    write_rows(path, rows)


def keep_rows(path: Path, pick: Callable[[int], bool]) -> None:
    rows = rows_of(path)
    write_rows(path, [rows[0]] + [r for k, r in enumerate(rows[1:]) if pick(k)])


def edit_yaml(folder: Path, **changes) -> None:
    y = yaml.safe_load((folder / "session.yaml").read_text())
    for k, v in changes.items():
        if v is _DROP:
            y.pop(k, None)
        else:
            y[k] = v
    (folder / "session.yaml").write_text(yaml.safe_dump(y, sort_keys=False))


_DROP = object()


def replace_text(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    if old not in text:
        raise SystemExit(f"sweep: a case needs {old!r} in {path}")
    path.write_text(text.replace(old, new, count))


def xyzw_order(path: Path, body: str) -> None:
    """Rewrite a rigid body's quaternion in x,y,z,w order under the spec's qw,qx,qy,qz names."""
    rows = rows_of(path)
    cols = [rows[0].index(f"{body}_q{a}") for a in "wxyz"]
    for r in rows[1:]:
        if r[cols[0]]:
            w, x, y, z = (r[c] for c in cols)
            r[cols[0]], r[cols[1]], r[cols[2]], r[cols[3]] = x, y, z, w
    write_rows(path, rows)


# ------------------------------------------------------------------ running a command line
def run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


# ------------------------------------------------------------------ fixtures shared by the cases
@dataclass
class Fixtures:
    root: Path
    clean: dict = field(default_factory=dict)       # stand -> clean session folder
    cal: dict = field(default_factory=dict)         # stand -> clean calibration.yaml
    rms_m: dict = field(default_factory=dict)       # stand -> clean fit rms, m
    reference: dict = field(default_factory=dict)   # stand -> markers predicted on the clean commands (N, 3M) m
    tiago: Path | None = None                       # a converted TIAGo day (training)
    tiago_other: Path | None = None                 # the other day
    tiago_cal: Path | None = None
    bodies: Path | None = None                      # a simulated stewart session with a rigid body
    imu: Path | None = None                         # a simulated stewart session with an IMU
    broad: dict = field(default_factory=dict)       # part name -> an IMU-only session from a real BROAD trial
    urdf: Path | None = None                        # the TIAGo URDF

    def copy(self, src: Path, work: Path, name: str = "s") -> Path:
        dst = work / name
        shutil.copytree(src, dst)
        return dst


def predicted_markers_m(cal_path: Path, commands: Path) -> np.ndarray:
    """The markers (N, 3 M) m a calibration predicts for a commands file (the sweep's own reading)."""
    cal = read_calibration(cal_path)
    U, t = read_commands(commands, cal)
    header, rows, ok = prediction_table(cal, U, t)
    cols = [i for i, h in enumerate(header) if h.endswith(("_x", "_y", "_z")) and h[:-2] in cal.marker_names]
    return rows[:, cols] * length_scale(cal.length_unit)


def build_fixtures(root: Path, verbs: set[str]) -> Fixtures:
    fx = Fixtures(root)
    for stand in ("stewart", "rotary"):
        clean = root / stand / "clean"
        shutil.copytree(example_session(stand), clean)
        fx.clean[stand] = clean
        rc, _, err = run_cli(["calibrate", str(clean), "--out", str(root / stand / "cal"), "--no-selection",
                              "--no-report", "--quiet"])
        if rc:
            raise SystemExit(f"sweep: the clean {stand} example does not calibrate: {err}")
        fx.cal[stand] = root / stand / "cal" / "calibration.yaml"
        rms = json.loads((root / stand / "cal" / "report.json").read_text())["rms_after"]
        fx.rms_m[stand] = rms * length_scale(read_calibration(fx.cal[stand]).length_unit)
        fx.reference[stand] = predicted_markers_m(fx.cal[stand], clean / "commands.csv")
    if TIAGO.is_dir() and verbs & {"calibrate", "predict", "fk", "track", "plan", "diagnose"}:
        try:
            from tests.real_data.tiago import TRAINING, VALIDATION, convert
        except ImportError:  # the converter's older place
            from benchmarks.datasets.tiago import TRAINING, VALIDATION, convert  # type: ignore[no-redef]
        fx.tiago = convert(TIAGO / TRAINING, root / "tiago" / "train")
        fx.tiago_other = convert(TIAGO / VALIDATION, root / "tiago" / "other")
        fx.urdf = TIAGO / "tiago_48_schunk.urdf"
        rc, _, err = run_cli(["calibrate", str(fx.tiago), "--free", "none", "--out", str(root / "tiago" / "cal"),
                              "--quiet", "--no-report"])
        if rc:
            raise SystemExit(f"sweep: the TIAGo training day does not calibrate: {err}")
        fx.tiago_cal = root / "tiago" / "cal" / "calibration.yaml"
    if verbs & {"calibrate", "diagnose"}:
        fx.bodies = root / "bodies"
        rc, _, err = run_cli(["simulate", "--platform", "stewart", "--out", str(fx.bodies), "--rigid-bodies", "1",
                              "--poses", "30", "--seed", "7"])
        if rc:
            raise SystemExit(f"sweep: simulate --rigid-bodies failed: {err}")
    if verbs & {"orient", "batch"}:
        fx.imu = root / "imu"
        rc, _, err = run_cli(["simulate", "--platform", "stewart", "--out", str(fx.imu), "--imu", "--poses", "12",
                              "--seed", "3"])
        if rc:
            raise SystemExit(f"sweep: simulate --imu failed: {err}")
    if verbs & {"orient"} and BROAD.is_dir():
        build_broad(fx, root / "broad")
    return fx


def build_broad(fx: Fixtures, root: Path) -> None:
    """IMU-only sessions from a real BROAD trial (tests/real_data/broad.py reads the HDF5 file):
    its opening rest (a stationary recording) and its first 60 s of motion after the rest."""
    from platkit.io.imu import write_imu_csv
    sys.path.insert(0, str(ROOT / "tests"))  # tests/real_data is imported as real_data, as the golden tests do
    from real_data.broad import read_broad

    tr = read_broad(BROAD / BROAD_TRIAL)
    start = int(np.argmax(tr.movement))
    n60 = int(60 * tr.rate_hz)
    for name, part in (("rest", slice(0, start - 300)), ("moving", slice(start, start + n60))):
        folder = root / name
        folder.mkdir(parents=True)
        (folder / "session.yaml").write_text(f"platform: none\nunits: {{length: m, time: s}}\nmarkers: []\n"
                                             f"imu: {{rate_hz: {tr.rate_hz:g}, frame: imu}}\n")
        write_imu_csv(folder / "imu.csv", tr.imu.t[part], tr.imu.gyr[part], tr.imu.acc[part])
        fx.broad[name] = folder


# ------------------------------------------------------------------ reading what a verb wrote
def report_warnings(name: str, key: str = "warnings") -> Callable[[Path, Fixtures, str], list[str]]:
    def read(work: Path, fx: Fixtures, stdout: str) -> list[str]:
        p = work / "out" / name
        return list(json.loads(p.read_text()).get(key, [])) if p.is_file() else []
    return read


def stdout_json_warnings(work: Path, fx: Fixtures, stdout: str) -> list[str]:
    try:
        return list(json.loads(stdout).get("warnings", []))
    except ValueError:
        return []


def plan_warnings(work: Path, fx: Fixtures, stdout: str) -> list[str]:
    p = work / "plan.json"
    return list(json.loads(p.read_text()).get("warnings", [])) if p.is_file() else []


def simulate_warnings(work: Path, fx: Fixtures, stdout: str) -> list[str]:
    p = work / "out" / "session.yaml"
    return [str((yaml.safe_load(p.read_text()) or {}).get("notes") or "")] if p.is_file() else []


def import_notes(work: Path, fx: Fixtures, stdout: str) -> list[str]:
    p = work / "out" / "session.yaml"
    return [str((yaml.safe_load(p.read_text()) or {}).get("notes") or "")] if p.is_file() else []


def batch_warnings(work: Path, fx: Fixtures, stdout: str) -> list[str]:
    out = []
    for p in sorted((work / "out").glob("sessions/*/task.json")):
        out += list(json.loads(p.read_text()).get("warnings", []))
    return out


# ------------------------------------------------------------------ checks against the truth
def calibration_agrees(stand: str) -> Callable[[Path, Fixtures, str], bool | None]:
    """The case's calibration predicts the clean commands' markers within 3x the clean fit's rms."""
    def check(work: Path, fx: Fixtures, stdout: str) -> bool | None:
        cal = work / "out" / "calibration.yaml"
        if not cal.is_file():
            return None
        got = predicted_markers_m(cal, fx.clean[stand] / "commands.csv")
        ref = fx.reference[stand]
        if got.shape != ref.shape:
            return False
        d = np.sqrt(np.nanmean(np.sum((got - ref).reshape(len(got), -1, 3) ** 2, axis=2)))
        return bool(d <= 3 * fx.rms_m[stand])
    return check


def prediction_agrees(stand: str, rows: slice = slice(None)) -> Callable[[Path, Fixtures, str], bool | None]:
    """predict's file: every marker cell of ``rows`` within 1 um of the clean commands' prediction."""
    def check(work: Path, fx: Fixtures, stdout: str) -> bool | None:
        p = work / "pred.csv"
        if not p.is_file():
            return None
        data = rows_of(p)
        header = data[0]
        names = read_calibration(fx.cal[stand]).marker_names
        cols = [i for i, h in enumerate(header) if h.endswith(("_x", "_y", "_z")) and h[:-2] in names]
        s = length_scale(read_calibration(fx.cal[stand]).length_unit)
        got = np.array([[float(r[i]) if r[i] else np.nan for i in cols] for r in data[1:]]) * s
        ref = fx.reference[stand]
        if got.shape != ref.shape:
            return False
        return bool(np.nanmax(np.abs(got[rows] - ref[rows])) < 1e-6)
    return check


def fk_agrees(expected_xyz: tuple[float, float, float], tol: float):
    def check(work: Path, fx: Fixtures, stdout: str) -> bool | None:
        try:
            d = json.loads(stdout)
        except ValueError:
            return None
        return bool(np.allclose([d["x"], d["y"], d["z"]], expected_xyz, atol=tol))
    return check


def judge(case: Case, rc: int, out: str, err: str, written: list[str] | None, agrees: bool | None) -> tuple[str, str]:
    """(class, why) of one run (see the module's docstring)."""
    if "run with --debug for the traceback" in err or "Traceback" in err:
        return "TRACEBACK", "unexpected exception"
    errors = [ln for ln in err.splitlines() if ln.startswith("platkit: error:")]
    stderr_warnings = [ln for ln in err.splitlines() if ln.startswith("platkit: warning:")]
    if rc != 0:
        for e in case.expect:
            if e.kind == "error" and rc == e.code and len(errors) == 1 and all(n in errors[0] for n in e.names):
                return "precise", "refused as expected"
        want = [e for e in case.expect if e.kind == "error"]
        if not want:
            return "vague", f"refused (exit {rc}) what should be kept"
        if not errors:
            return "vague", f"exit {rc} without a platkit: error line"
        if len(errors) > 1:
            return "vague", f"{len(errors)} error lines"
        if all(rc != e.code for e in want):
            return "vague", f"exit {rc}, expected {want[0].code}"
        missing = [n for n in want[0].names if n not in errors[0]]
        return "vague", f"the line does not name {', '.join(map(repr, missing))}"
    # exit 0
    kept = written if written is not None else [w.removeprefix("platkit: warning: ") for w in stderr_warnings]
    said_any = bool(kept or stderr_warnings)
    if agrees is False and not said_any:
        return "SILENT-WRONG", "exit 0, no warning, the result does not agree"
    for e in case.expect:
        if e.kind == "warning" and any(all(n in w for n in e.names) for w in kept):
            return "precise", "warned as expected"
        if e.kind == "accepted" and agrees is not False:
            return "precise", "accepted" + (" (checked)" if agrees else "")
    if said_any:
        if stderr_warnings and written is not None and not written:
            return "vague", "warned on stderr only, not in the written outputs"
        return "vague", "warned, but not as expected"
    if agrees is True:
        return "precise", "accepted, and the result agrees"
    return "SILENT-WRONG", "exit 0 and no warning for a bad input"


# ------------------------------------------------------------------ the cases
def session_cases() -> list[Case]:
    """calibrate on the shipped sessions (stewart, rotary), one thing wrong each."""
    return _session_cases("stewart") + _session_cases("rotary")


def _session_cases(stand: str) -> list[Case]:
    from platkit.plugins import get_platform

    cases: list[Case] = []
    spec = get_platform(stand)
    c0 = spec.controls[0]
    unit_k = 1e3 if c0.unit == "m" else 1.0  # the example files write 'm' controls in mm
    first = spec.control_names[0]
    stroke = (c0.upper - c0.lower) * unit_k
    upper = c0.upper * unit_k

    def sess(edit, stand=stand):
        def make(work: Path, fx: Fixtures) -> list[str]:
            f = fx.copy(fx.clean[stand], work)
            edit(f)
            return ["calibrate", str(f), "--out", str(work / "out"), "--no-selection", "--no-report", "--quiet"]
        return make

    def add(name, edit, *expect, check=True, stand=stand):
        cases.append(Case("calibrate", f"{stand}: {name}", sess(edit, stand), tuple(expect),
                          report_warnings("report.json"), calibration_agrees(stand) if check else None))

    m0, m1 = "M1", "M2"
    add("times in ms declared s", lambda f: (scale_column(f / "markers.csv", "t", 1e3),
                                             scale_column(f / "commands.csv", "t", 1e3)),
        error(2, "session.yaml", "milliseconds"))
    add("times in s declared ms", lambda f: edit_yaml(f, units={"length": "mm", "time": "ms"}),
        error(2, "session.yaml", "seconds"))
    add("mocap_rate_hz wrong (x5)",
        lambda f: edit_yaml(f, mocap_rate_hz=5 * float(yaml.safe_load((f / "session.yaml").read_text())["mocap_rate_hz"])),
        error(2, "mocap_rate_hz"))
    add("command log in ms, stream in s", lambda f: scale_column(f / "commands.csv", "t", 1e3),
        error(2, "commands.csv"))
    add("markers in m declared mm", lambda f: scale_suffix(f / "markers.csv", ("_x", "_y", "_z"), 1e-3),
        error(2, "markers.csv", "metres"))
    add("markers in um declared mm", lambda f: scale_suffix(f / "markers.csv", ("_x", "_y", "_z"), 1e3),
        error(2, "markers.csv"))
    add("length unit declared m", lambda f: edit_yaml(f, units={"length": "m", "time": "s"}),
        error(2, "markers.csv"), error(2, "commands.csv", "declares m"))
    add("x columns of two markers swapped", lambda f: swap_headers(f / "markers.csv", f"{m0}_x", f"{m1}_x"),
        error(2, "markers.csv"), warning(m0))
    add("a marker slips 5 mm half-way", lambda f: _slip(f / "markers.csv", m0, 5.0), warning(m0))
    add("control 0.5% past its limit", lambda f: edit_cell(f / "commands.csv", 3, first, f"{upper + 0.005 * stroke:.9g}"),
        warning("commands.csv", f"'{first}'", "past the limit"))
    add("control 5% past its limit", lambda f: edit_cell(f / "commands.csv", 3, first, f"{upper + 0.05 * stroke:.9g}"),
        error(2, "commands.csv", f"'{first}'", "outside the stroke"))
    if unit_k > 1:
        add("controls in m, declared mm", lambda f: scale_suffix(f / "commands.csv", tuple(spec.control_names), 1e-3),
            error(2, "commands.csv", f"'{first}'"))
    else:
        add("controls in rad, the spec's deg", lambda f: scale_suffix(f / "commands.csv", tuple(spec.control_names), np.pi / 180),
            warning("control columns", "units"), error(2, "commands.csv"))
    add("text in a control cell", lambda f: edit_cell(f / "commands.csv", 2, first, "abc"),
        error(2, "commands.csv", "row 2", f"'{first}'"))
    add("empty control cell", lambda f: edit_cell(f / "commands.csv", 2, first, ""),
        error(2, "commands.csv", "row 2", f"'{first}'"))
    add("nan control cell", lambda f: edit_cell(f / "commands.csv", 2, first, "nan"),
        error(2, "commands.csv", "row 2", f"'{first}'"))
    add("inf in a marker cell", lambda f: edit_cell(f / "markers.csv", 7, f"{m0}_y", "inf"),
        error(2, "markers.csv", f"{m0}_y"))
    add("nan marker cell (an occluded sample)", lambda f: edit_cell(f / "markers.csv", 7, f"{m0}_y", "nan"),
        error(2, "markers.csv", f"{m0}"), accepted())
    add("cut line in markers.csv", lambda f: _cut(f / "markers.csv"), error(2, "markers.csv", "row 5"))
    add("duplicated timestamp", lambda f: edit_cell(f / "markers.csv", 4, "t", rows_of(f / "markers.csv")[3][0]),
        error(2, "markers.csv", "'t'"))
    add("markers.csv rows out of time order", lambda f: swap_rows(f / "markers.csv", 10, 11),
        error(2, "markers.csv", "'t'"))
    add("commands.csv rows out of time order", lambda f: swap_rows(f / "commands.csv", 4, 5),
        error(2, "commands.csv", "'t'"))
    add("semicolon separator", lambda f: (f / "commands.csv").write_text((f / "commands.csv").read_text().replace(",", ";")),
        accepted())
    add("semicolons and decimal commas",
        lambda f: (f / "commands.csv").write_text((f / "commands.csv").read_text().replace(",", ";").replace(".", ",")),
        accepted())
    add("CRLF line ends and a BOM",
        lambda f: (f / "markers.csv").write_bytes(b"\xef\xbb\xbf" + (f / "markers.csv").read_bytes().replace(b"\n", b"\r\n")),
        accepted())
    add("commands.csv missing", lambda f: (f / "commands.csv").unlink(), error(2, "commands.csv"))
    add("markers.csv missing", lambda f: (f / "markers.csv").unlink(), error(2, "markers.csv"))
    add("markers.csv empty (0 bytes)", lambda f: (f / "markers.csv").write_text(""), error(2, "markers.csv"))
    add("markers.csv header only", lambda f: write_rows(f / "markers.csv", rows_of(f / "markers.csv")[:1]),
        error(2, "markers.csv"))
    add("commands.csv empty (0 bytes)", lambda f: (f / "commands.csv").write_text(""), error(2, "commands.csv"))
    add("a control column missing", lambda f: drop_column(f / "commands.csv", first),
        error(2, "commands.csv", f"'{first}'"))
    add("an unknown column in commands.csv", lambda f: rename_column(f / "commands.csv", first, "Lx"),
        error(2, "commands.csv", "'Lx'"))
    add("a declared marker has no columns", lambda f: drop_columns_like(f / "markers.csv", f"{m1}_"),
        error(2, "markers.csv", m1))
    add("undeclared marker column", lambda f: edit_yaml(f, markers=[m for m in ("M1", "M3", "M4", "M5")]),
        error(2, "markers.csv", m1))
    add("a marker never seen (all empty)", lambda f: _blank_marker(f / "markers.csv", m1),
        error(2, "markers.csv", m1), warning(m1))
    add("unknown platform", lambda f: edit_yaml(f, platform="nosuch"), error(2, "session.yaml", "nosuch"))
    add("the other stand declared", lambda f: edit_yaml(f, platform="rotary" if stand == "stewart" else "stewart"),
        error(2, "commands.csv"))
    add("session.yaml malformed", lambda f: (f / "session.yaml").write_text("platform: [stewart\nunits: {length: mm"),
        error(2, "session.yaml"))
    add("session.yaml empty", lambda f: (f / "session.yaml").write_text(""), error(2, "session.yaml"))
    add("units missing", lambda f: edit_yaml(f, units=_DROP), error(2, "session.yaml", "units"))
    add("mocap_rate_hz negative", lambda f: edit_yaml(f, mocap_rate_hz=-40), error(2, "session.yaml", "mocap_rate_hz"))
    add("description file missing", lambda f: edit_yaml(f, description="nosuch.yaml"),
        error(2, "nosuch.yaml"))
    add("clocks that do not overlap (markers +10000 s)", lambda f: shift_column(f / "markers.csv", "t", 1e4),
        error(2, "markers.csv", "commands.csv"))
    add("command log sparser than the motion (every 2nd row)", lambda f: keep_rows(f / "commands.csv", lambda k: k % 2 == 0),
        error(2, "commands.csv"), warning("command log holds every command"))
    add("command log ends half-way", lambda f: keep_rows(f / "commands.csv", lambda k: k < 40),
        warning("commands.csv"), accepted())
    return cases


def _slip(path: Path, marker: str, mm: float) -> None:
    rows = rows_of(path)
    j = rows[0].index(f"{marker}_x")
    for r in rows[len(rows) // 2:]:
        if r[j]:
            r[j] = f"{float(r[j]) + mm:.6f}"
    write_rows(path, rows)


def _cut(path: Path) -> None:
    rows = rows_of(path)
    rows[5] = rows[5][:-2]
    write_rows(path, rows)


def _blank_marker(path: Path, marker: str) -> None:
    rows = rows_of(path)
    cols = [rows[0].index(f"{marker}_{a}") for a in "xyz"]
    for r in rows[1:]:
        for c in cols:
            r[c] = ""
    write_rows(path, rows)


def body_cases() -> list[Case]:
    """calibrate on a simulated stewart session with a rigid body T1 (and markers)."""
    def make(edit, extra=(), selection=True):
        def m(work: Path, fx: Fixtures) -> list[str]:
            f = fx.copy(fx.bodies, work)
            edit(f)
            return ["calibrate", str(f), "--out", str(work / "out"), *(["--no-selection"] if selection else []),
                    "--no-report", "--quiet", *extra]
        return m

    out = report_warnings("report.json")
    return [
        Case("calibrate", "bodies: clean", make(lambda f: None), (accepted(),), out),
        Case("calibrate", "bodies: quaternion in x,y,z,w order", make(lambda f: xyzw_order(f / "markers.csv", "T1")),
             (error(2, "T1", "x,y,z,w"), error(2, "T1", "order")), out),
        Case("calibrate", "bodies: quaternion not unit (x2)",
             make(lambda f: scale_suffix(f / "markers.csv", ("_qw", "_qx", "_qy", "_qz"), 2.0)),
             (error(2, "markers.csv", "T1"),), out),
        Case("calibrate", "bodies: a quaternion column missing", make(lambda f: drop_column(f / "markers.csv", "T1_qz")),
             (error(2, "markers.csv", "T1"),), out),
        Case("calibrate", "bodies: the body alone (no markers)",
             make(lambda f: (drop_columns_like(f / "markers.csv", "M"), edit_yaml(f, markers=[]))),
             (accepted(), warning("T1")), out),
        Case("calibrate", "bodies: --method paper (markers only)", make(lambda f: None, ("--method", "paper"), selection=False),
             (warning("T1", "left out"), error(2, "T1"), error(1)), out),
    ]


def tiago_cases() -> list[Case]:
    """calibrate on the real TIAGo day (URDF stand, settled poses in metres)."""
    def make(edit, extra=("--free", "none")):
        def m(work: Path, fx: Fixtures) -> list[str]:
            f = fx.copy(fx.tiago, work)
            edit(f)
            return ["calibrate", str(f), "--out", str(work / "out"), "--quiet", "--no-report", *extra]
        return m

    out = report_warnings("report.json")
    urdf = "tiago_48_schunk.urdf"
    return [
        Case("calibrate", "tiago: the real day as recorded (torso 0.350181 m)", make(lambda f: None),
             (warning("torso_lift_joint", "past the limit 0.35 m"), accepted()), out),
        Case("calibrate", "tiago: moving_link not in the URDF", make(lambda f: edit_yaml(f, moving_link="hand_link_x")),
             (error(2, "hand_link_x"),), out),
        Case("calibrate", "tiago: a joint column not in the URDF",
             make(lambda f: (rename_column(f / "commands.csv", "arm_7_joint", "arm_9_joint"),
                             rename_column(f / "poses.csv", "arm_7_joint", "arm_9_joint"))),
             (error(2, "arm_9_joint"), error(2, "arm_7_joint")), out),
        Case("calibrate", "tiago: URDF truncated", make(lambda f: (f / urdf).write_text((f / urdf).read_text()[:5000])),
             (error(2, urdf),), out),
        Case("calibrate", "tiago: URDF not XML", make(lambda f: (f / urdf).write_text("robot: tiago\n")),
             (error(2, urdf),), out),
        Case("calibrate", "tiago: a link's mass negative",
             make(lambda f: replace_text(f / urdf, '<mass value="', '<mass value="-')),
             (error(2, urdf, "mass"), accepted(), warning("mass")), out),
        Case("calibrate", "tiago: a mimic joint's master missing",
             make(lambda f: _mimic_missing(f / urdf)),
             (error(2, urdf, "nosuch_joint"), error(2, "nosuch_joint")), out),
        Case("calibrate", "tiago: arm joints in degrees (spec: rad)",
             make(lambda f: (scale_columns(f / "commands.csv", [f"arm_{k}_joint" for k in range(1, 8)], 180 / np.pi),
                             scale_columns(f / "poses.csv", [f"arm_{k}_joint" for k in range(1, 8)], 180 / np.pi))),
             (error(2, "arm_"),), out),
        Case("calibrate", "tiago: markers in mm declared m",
             make(lambda f: scale_suffix(f / "poses.csv", ("_x", "_y", "_z"), 1e3)), (error(2, "poses.csv"),), out),
        Case("calibrate", "tiago: torso 5% past its limit",
             make(lambda f: (edit_cell(f / "commands.csv", 3, "torso_lift_joint", "0.3675"),
                             edit_cell(f / "poses.csv", 3, "torso_lift_joint", "0.3675"))),
             (error(2, "torso_lift_joint", "outside the stroke"),), out),
        Case("calibrate", "tiago: poses.csv and commands.csv disagree",
             make(lambda f: edit_cell(f / "commands.csv", 3, "arm_1_joint", "0.5")),
             (error(2, "commands.csv"), error(2, "poses.csv"), accepted()), out),
        Case("calibrate", "tiago: one coordinate of a marker nan in poses.csv",
             make(lambda f: edit_cell(f / "poses.csv", 3, "BL_x", "nan")), (error(2, "poses.csv", "BL"),), out),
        Case("calibrate", "tiago: a marker occluded in one pose (x,y,z nan)",
             make(lambda f: [edit_cell(f / "poses.csv", 3, f"BL_{a}", "nan") for a in "xyz"]), (accepted(), warning("BL")), out),
    ]


def method_cases() -> list[Case]:
    """calibrate --method paper on the shipped sessions: a method that fits worse than the
    geometric model's own start says so in report.json, or fails."""
    def make(stand):
        def m(work: Path, fx: Fixtures) -> list[str]:
            return ["calibrate", str(fx.clean[stand]), "--out", str(work / "out"), "--method", "paper", "--no-report",
                    "--quiet"]
        return m

    def agrees_or_said(stand):
        return calibration_agrees(stand)

    return [Case("calibrate", f"{stand}: --method paper", make(stand), (accepted(), warning("paper"), error(1)),
                 report_warnings("report.json"), agrees_or_said(stand)) for stand in ("stewart", "rotary")]


def predict_cases() -> list[Case]:
    cases = _predict_cases("stewart") + _predict_cases("rotary")
    _predict_other_cases(cases)
    return cases


def _predict_cases(stand: str) -> list[Case]:
    from platkit.plugins import get_platform

    cases: list[Case] = []
    spec = get_platform(stand)
    c0 = spec.controls[0]
    unit_k = 1e3 if c0.unit == "m" else 1.0
    first = spec.control_names[0]
    stroke = (c0.upper - c0.lower) * unit_k
    upper = c0.upper * unit_k

    def add(name, edit, *expect, check=None, stand=stand):
        def make(work: Path, fx: Fixtures) -> list[str]:
            cmd = work / "commands.csv"
            shutil.copy(fx.clean[stand] / "commands.csv", cmd)
            edit(cmd)
            return ["predict", "--calibration", str(fx.cal[stand]), "--commands", str(cmd), "--out", str(work / "pred.csv")]
        cases.append(Case("predict", f"{stand}: {name}", make, tuple(expect), None, check))

    add("clean commands", lambda p: None, accepted(), check=prediction_agrees(stand))
    add("control 0.5% past its limit", lambda p: edit_cell(p, 3, first, f"{upper + 0.005 * stroke:.9g}"),
        warning("commands.csv", f"'{first}'", "past the limit"))
    add("control 5% past its limit", lambda p: edit_cell(p, 3, first, f"{upper + 0.05 * stroke:.9g}"),
        error(2, "commands.csv", f"'{first}'", "outside the stroke"))
    add("text in a control cell", lambda p: edit_cell(p, 2, first, "abc"), error(2, "commands.csv", "row 2", f"'{first}'"))
    add("empty control cell", lambda p: edit_cell(p, 2, first, ""), error(2, "commands.csv", "row 2", f"'{first}'"))
    add("a control column missing", lambda p: drop_column(p, first), error(2, "commands.csv", f"'{first}'"))
    add("semicolon separator", lambda p: p.write_text(p.read_text().replace(",", ";")), accepted(),
        check=prediction_agrees(stand))
    add("times in ms (t is the order only)", lambda p: scale_column(p, "t", 1e3), accepted(),
        check=prediction_agrees(stand))
    add("rows out of time order", lambda p: swap_rows(p, 4, 5), error(2, "commands.csv", "'t'"), accepted())
    add("empty file", lambda p: p.write_text(""), error(2, "commands.csv"))
    if unit_k > 1:
        add("controls in m, the calibration's mm", lambda p: scale_suffix(p, tuple(spec.control_names), 1e-3),
            error(2, "commands.csv", f"'{first}'"))
    return cases


def _predict_other_cases(cases: list[Case]) -> None:
    def other(name, make_, *expect):
        cases.append(Case("predict", name, make_, tuple(expect)))

    def tiago_next_day(work: Path, fx: Fixtures) -> list[str]:
        return ["predict", "--calibration", str(fx.tiago_cal), "--commands", str(fx.tiago_other / "commands.csv"),
                "--out", str(work / "pred.csv")]

    other("tiago: the next day's commands (torso 0.350066 m)", tiago_next_day,
          warning("torso_lift_joint", "past the limit 0.35 m"))

    def missing_cal(work: Path, fx: Fixtures) -> list[str]:
        return ["predict", "--calibration", str(work / "nosuch.yaml"), "--commands", str(fx.clean["stewart"] / "commands.csv"),
                "--out", str(work / "pred.csv")]

    other("calibration.yaml missing", missing_cal, error(2, "nosuch.yaml"))

    def bad_cal(work: Path, fx: Fixtures) -> list[str]:
        (work / "calibration.yaml").write_text("platform: stewart\nparameters: [1, 2\n")
        return ["predict", "--calibration", str(work / "calibration.yaml"), "--commands",
                str(fx.clean["stewart"] / "commands.csv"), "--out", str(work / "pred.csv")]

    other("calibration.yaml malformed", bad_cal, error(2, "calibration.yaml"))

    def other_stand(work: Path, fx: Fixtures) -> list[str]:
        return ["predict", "--calibration", str(fx.cal["rotary"]), "--commands", str(fx.clean["stewart"] / "commands.csv"),
                "--out", str(work / "pred.csv")]

    other("commands of another stand", other_stand, error(2, "commands.csv"))


def diagnose_cases() -> list[Case]:
    out = report_warnings("diagnosis.json")

    def make(stand, edit=lambda f: None, cal=None, extra=()):
        def m(work: Path, fx: Fixtures) -> list[str]:
            f = fx.copy(fx.clean[stand] if stand in fx.clean else getattr(fx, stand), work)
            edit(f)
            c = cal(work, fx) if cal else str(fx.cal[stand])
            return ["diagnose", str(f), "--calibration", c, "--out", str(work / "out"), "--quiet", *extra]
        return m

    def bad_yaml(work: Path, fx: Fixtures) -> str:
        (work / "calibration.yaml").write_text("platform: rotary\n  parameters: {")
        return str(work / "calibration.yaml")

    def first_past(f: Path) -> None:
        edit_cell(f / "commands.csv", 3, "u1", "181.8")

    def bodies_cal(work: Path, fx: Fixtures) -> str:
        run_cli(["calibrate", str(fx.bodies), "--out", str(work / "bcal"), "--no-selection", "--no-report", "--quiet"])
        return str(work / "bcal" / "calibration.yaml")

    return [
        Case("diagnose", "rotary: clean (no finding)", make("rotary"), (accepted(),), out),
        Case("diagnose", "rotary: control 0.5% past its limit", make("rotary", first_past),
             (warning("commands.csv", "'u1'", "past the limit"),), out),
        Case("diagnose", "rotary: control 5% past its limit",
             make("rotary", lambda f: edit_cell(f / "commands.csv", 3, "u1", "198")),
             (error(2, "commands.csv", "'u1'"),), out),
        Case("diagnose", "rotary: calibration of another stand", make("rotary", cal=lambda w, fx: str(fx.cal["stewart"])),
             (error(2, "calibration"),), out),
        Case("diagnose", "rotary: calibration.yaml missing", make("rotary", cal=lambda w, fx: str(w / "nosuch.yaml")),
             (error(2, "nosuch.yaml"),), out),
        Case("diagnose", "rotary: calibration.yaml malformed", make("rotary", cal=bad_yaml),
             (error(2, "calibration.yaml"),), out),
        Case("diagnose", "rotary: times in ms declared s",
             make("rotary", lambda f: (scale_column(f / "markers.csv", "t", 1e3), scale_column(f / "commands.csv", "t", 1e3))),
             (error(2, "milliseconds"),), out),
        Case("diagnose", "rotary: markers in m declared mm",
             make("rotary", lambda f: scale_suffix(f / "markers.csv", ("_x", "_y", "_z"), 1e-3)),
             (error(2, "markers.csv"),), out),
        Case("diagnose", "rotary: markers.csv missing", make("rotary", lambda f: (f / "markers.csv").unlink()),
             (error(2, "markers.csv"),), out),
        Case("diagnose", "rotary: clocks that do not overlap",
             make("rotary", lambda f: shift_column(f / "markers.csv", "t", 1e4)),
             (error(2, "markers.csv"),), out),
        Case("diagnose", "rotary: --folds 1", make("rotary", extra=("--folds", "1")), (error(2, "--folds"),), out),
        Case("diagnose", "rotary: --alpha 2", make("rotary", extra=("--alpha", "2")), (error(2, "--alpha"),), out),
        Case("diagnose", "bodies: rigid bodies read as points", make("bodies", cal=bodies_cal),
             (warning("T1", "three points"),), out),
    ]


def fk_ik_cases() -> list[Case]:
    cases: list[Case] = []

    def fk(name, argv, *expect, check=None):
        cases.append(Case("fk", name, lambda w, fx, a=argv: ["fk", *a, "--json"], tuple(expect), stdout_json_warnings,
                          check))

    def ik(name, argv, *expect):
        cases.append(Case("ik", name, lambda w, fx, a=argv: ["ik", *a, "--json"], tuple(expect)))

    fk("stewart: neutral controls", ["--platform", "stewart", "--u", "4045,4045,4045,4045,4045,4045"], accepted())
    fk("stewart: five controls for six", ["--platform", "stewart", "--u", "4045,4045,4045,4045,4045"], error(2, "--u", "6"))
    fk("stewart: text in --u", ["--platform", "stewart", "--u", "a,b,c,d,e,f"], error(2, "--u"))
    fk("stewart: nan in --u", ["--platform", "stewart", "--u", "nan,4045,4045,4045,4045,4045"], error(2, "--u"))
    fk("stewart: controls in m with --unit mm", ["--platform", "stewart", "--u", "4.045,4.045,4.045,4.045,4.045,4.045"],
       error(2, "L1", "outside the stroke"), error(1, "L1", "outside the stroke"))
    fk("rotary: a control 0.5% past its limit", ["--platform", "rotary", "--u", "181.8,0"],
       warning("u1", "past the limit"))
    fk("rotary: a control 5% past its limit", ["--platform", "rotary", "--u", "198,0"],
       error(2, "u1", "outside the stroke"), error(1, "u1", "outside the stroke"))
    fk("rotary: controls in rad (spec: deg)", ["--platform", "rotary", "--u", "0.5,0.2"], accepted())
    fk("unknown platform", ["--platform", "nosuch", "--u", "1,2"], error(2, "nosuch"))
    fk("description file missing", ["--platform", "stewart", "--description", "/nonexistent/d.yaml", "--u", "1,2,3,4,5,6"],
       error(2, "d.yaml"))
    ik("stewart: an unreachable pose (z 10 m)", ["--platform", "stewart", "--pose", "0,0,10000,0,0,0"], error(1))
    ik("stewart: four numbers", ["--platform", "stewart", "--pose", "0,0,1000,0"], error(2, "--pose"))
    ik("stewart: a zero quaternion", ["--platform", "stewart", "--pose", "0,0,3300,0,0,0,0"], error(2, "--pose", "quaternion"))
    ik("stewart: a quaternion not unit (x2)", ["--platform", "stewart", "--pose", "0,0,3300,2,0,0,0"],
       error(2, "--pose", "quaternion"), warning("quaternion"))
    ik("stewart: nan in --pose", ["--platform", "stewart", "--pose", "0,nan,3300,0,0,0"], error(2, "--pose"))
    ik("stewart: a pose in m with --unit mm", ["--platform", "stewart", "--pose", "0,0,3.3,0,0,0"], error(1))
    ik("stewart: roll in degrees (spec: rad)", ["--platform", "stewart", "--pose", "0,0,3300,20,0,0"], error(1))
    return cases


def simulate_cases() -> list[Case]:
    out = simulate_warnings

    def sim(name, argv_fn, *expect):
        def make(work: Path, fx: Fixtures) -> list[str]:
            return ["simulate", "--out", str(work / "out"), "--poses", "12", *argv_fn(work)]
        return Case("simulate", name, make, tuple(expect), out)

    def plan_file(rows: list[str], header="L1,L2,L3,L4,L5,L6"):
        def write(work: Path) -> list[str]:
            (work / "plan.csv").write_text(header + "\n" + "\n".join(rows) + "\n")
            return ["--platform", "stewart", "--plan", str(work / "plan.csv")]
        return write

    neutral = "4045,4045,4045,4045,4045,4045"
    return [
        sim("clean", lambda w: ["--platform", "stewart"], accepted()),
        sim("plan: a control 0.5% past its limit", plan_file([neutral, "4802.5,4045,4045,4045,4045,4045", neutral]),
            warning("plan.csv", "'L1'", "past the limit")),
        sim("plan: a control 5% past its limit", plan_file([neutral, "4870,4045,4045,4045,4045,4045", neutral]),
            error(2, "plan.csv", "L1")),
        sim("plan: text in a cell", plan_file([neutral, "abc,4045,4045,4045,4045,4045", neutral]), error(2, "plan.csv", "L1")),
        sim("plan: a control column missing", plan_file(["4045,4045,4045,4045,4045"] * 3, "L1,L2,L3,L4,L5"),
            error(2, "plan.csv", "L6")),
        sim("plan: empty file",
            lambda w: ((w / "plan.csv").write_text(""), ["--platform", "stewart", "--plan", str(w / "plan.csv")])[1],
            error(2, "plan.csv")),
        sim("plan: controls in m (declared mm)", plan_file(["4.045,4.045,4.045,4.045,4.045,4.045"] * 3),
            error(2, "plan.csv", "L1")),
        sim("--effect unknown", lambda w: ["--platform", "stewart", "--effect", "wobble:3"], error(2, "wobble")),
        sim("--effect size not a number", lambda w: ["--platform", "stewart", "--effect", "backlash:big"], error(2, "backlash")),
        sim("--poses 2", lambda w: ["--platform", "stewart", "--poses", "2"], error(2, "--poses")),
        sim("--rate-hz 0", lambda w: ["--platform", "stewart", "--rate-hz", "0"], error(2, "--rate-hz")),
        sim("unknown platform", lambda w: ["--platform", "nosuch"], error(2, "nosuch")),
        sim("description malformed", lambda w: ((w / "d.yaml").write_text("name: [x\n"),
                                               ["--platform", "stewart", "--description", str(w / "d.yaml")])[1],
            error(2, "d.yaml")),
        sim("--out an existing file", lambda w: ((w / "out").write_text("x"), ["--platform", "stewart"])[1], error(2, "--out")),
        sim("--physics, plan: a control 0.5% past its limit",
            lambda w: plan_file([neutral, "4802.5,4045,4045,4045,4045,4045", neutral])(w) + ["--physics"],
            warning("plan.csv", "'L1'", "past the limit")),
    ]


def plan_cases() -> list[Case]:
    def plan(name, argv_fn, *expect):
        def make(work: Path, fx: Fixtures) -> list[str]:
            return ["plan", "--out", str(work / "plan.csv"), *argv_fn(work, fx)]
        return Case("plan", name, make, tuple(expect), plan_warnings)

    def tiago_desc(edit):
        def argv(work: Path, fx: Fixtures) -> list[str]:
            u = work / "tiago.urdf"
            u.write_text(fx.urdf.read_text())
            edit(u)
            return ["--platform", "urdf", "--description", str(u), "--moving-link", "wrist_ft_tool_link", "--grid", "2"]
        return argv

    return [
        plan("stewart: --grid 2", lambda w, fx: ["--platform", "stewart", "--grid", "2"], accepted()),
        plan("--grid 0", lambda w, fx: ["--platform", "stewart", "--grid", "0"], error(2, "--grid")),
        plan("--optimal 0", lambda w, fx: ["--platform", "stewart", "--optimal", "0"], error(2, "--optimal")),
        plan("--margin 0.6", lambda w, fx: ["--platform", "stewart", "--grid", "2", "--margin", "0.6"], error(2, "--margin")),
        plan("--noise-mm -1", lambda w, fx: ["--platform", "stewart", "--grid", "2", "--noise-mm", "-1"], error(2, "--noise-mm")),
        plan("--out not a .csv", lambda w, fx: ["--platform", "stewart", "--grid", "2", "--out", str(w / "plan.txt")],
             error(2, "--out")),
        plan("--compare without --monte-carlo", lambda w, fx: ["--platform", "stewart", "--grid", "2", "--compare", "x.csv"],
             error(2, "--monte-carlo")),
        plan("unknown platform", lambda w, fx: ["--platform", "nosuch", "--grid", "2"], error(2, "nosuch")),
        plan("tiago: URDF truncated", tiago_desc(lambda u: u.write_text(u.read_text()[:5000])), error(2, "tiago.urdf")),
        plan("tiago: a mimic joint's master missing",
             tiago_desc(lambda u: _mimic_missing(u)), error(2, "nosuch_joint")),
        plan("tiago: --moving-link not in the URDF",
             lambda w, fx: ["--platform", "urdf", "--description", str(fx.urdf), "--moving-link", "nolink", "--grid", "2"],
             error(2, "nolink")),
    ]


def track_cases() -> list[Case]:
    def track(name, argv_fn, *expect):
        def make(work: Path, fx: Fixtures) -> list[str]:
            return ["track", "--out", str(work / "path.csv"), "--json", *argv_fn(work, fx)]
        return Case("track", name, make, tuple(expect), stdout_json_warnings)

    reach = "0.6,0.2,0.8"

    def base(w, fx, *rest, urdf=None):
        return ["--urdf", str(urdf or fx.urdf), "--link", "arm_tool_link", *rest]

    def traj(text):
        def argv(w, fx):
            (w / "traj.csv").write_text(text)
            return base(w, fx, "--trajectory", str(w / "traj.csv"))
        return argv

    def urdf_edit(edit):
        def argv(w, fx):
            u = w / "robot.urdf"
            u.write_text(fx.urdf.read_text())
            edit(u)
            return base(w, fx, "--target", reach, urdf=u)
        return argv

    good_traj = "t,x,y,z\n0,0.6,0.2,0.8\n1,0.6,0.25,0.8\n"
    return [
        track("tiago: a reachable target", lambda w, fx: base(w, fx, "--target", reach), accepted()),
        track("--urdf missing", lambda w, fx: ["--urdf", str(w / "nosuch.urdf"), "--link", "arm_tool_link", "--target", reach],
              error(2, "nosuch.urdf")),
        track("--link not in the URDF", lambda w, fx: ["--urdf", str(fx.urdf), "--link", "nolink", "--target", reach],
              error(2, "nolink")),
        track("an unreachable target (5 m)", lambda w, fx: base(w, fx, "--target", "5,0,0"), error(1)),
        track("a target in mm with --unit m", lambda w, fx: base(w, fx, "--target", "600,200,800"), error(1)),
        track("--target with four numbers", lambda w, fx: base(w, fx, "--target", "0.6,0.2,0.8,1"), error(2, "--target")),
        track("--q0 a joint 0.5% past its limit", lambda w, fx: base(w, fx, "--target", reach, "--q0", "arm_1_joint=2.7631"),
              warning("arm_1_joint", "past the limit")),
        track("--q0 a joint 5% past its limit", lambda w, fx: base(w, fx, "--target", reach, "--q0", "arm_1_joint=3.0"),
              error(2, "--q0", "arm_1_joint")),
        track("--q0 an unknown joint", lambda w, fx: base(w, fx, "--target", reach, "--q0", "arm_9_joint=0"),
              error(2, "--q0", "arm_9_joint")),
        track("trajectory: clean", traj(good_traj), accepted()),
        track("trajectory: nan", traj("t,x,y,z\n0,0.6,nan,0.8\n1,0.6,0.25,0.8\n"), error(2, "traj.csv", "'y'")),
        track("trajectory: times decrease", traj("t,x,y,z\n1,0.6,0.2,0.8\n0,0.6,0.25,0.8\n"), error(2, "traj.csv", "'t'")),
        track("trajectory: a column missing", traj("t,x,y\n0,0.6,0.2\n1,0.6,0.25\n"), error(2, "traj.csv", "'z'")),
        track("trajectory: empty file", traj(""), error(2, "traj.csv")),
        track("trajectory: half a quaternion", traj("t,x,y,z,qw,qx\n0,0.6,0.2,0.8,1,0\n1,0.6,0.25,0.8,1,0\n"),
              error(2, "traj.csv", "'qy'")),
        track("URDF: a mimic joint's master missing",
              urdf_edit(lambda u: _mimic_missing(u)), error(2, "nosuch_joint")),
        track("URDF: truncated", urdf_edit(lambda u: u.write_text(u.read_text()[:5000])), error(2, "robot.urdf")),
    ]


def orient_cases() -> list[Case]:
    out = report_warnings("report.json")

    def orient(name, edit, *expect, extra=()):
        def make(work: Path, fx: Fixtures) -> list[str]:
            f = fx.copy(fx.imu, work)
            edit(f)
            return ["orient", str(f), "--out", str(work / "out"), *extra]
        return Case("orient", name, make, tuple(expect), out)

    def broad(part, name, edit, *expect):
        def make(work: Path, fx: Fixtures) -> list[str]:
            f = fx.copy(fx.broad[part], work)
            edit(f)
            return ["orient", str(f), "--out", str(work / "out")]
        return Case("orient", name, make, tuple(expect), out)

    gyr = ("gyr_x", "gyr_y", "gyr_z")
    acc = ("acc_x", "acc_y", "acc_z")

    def gap(f: Path, n: int) -> None:
        rows = rows_of(f / "imu.csv")
        for r in rows[50:50 + n]:
            for j in range(1, 7):
                r[j] = ""
        write_rows(f / "imu.csv", rows)

    return [
        orient("clean", lambda f: None, accepted()),
        orient("gyro in deg/s", lambda f: scale_columns(f / "imu.csv", list(gyr), 180 / np.pi), error(2, "imu.csv", "deg/s")),
        orient("accelerometer in g", lambda f: scale_columns(f / "imu.csv", list(acc), 1 / 9.80665), error(2, "imu.csv", "acc")),
        orient("imu times in ms", lambda f: scale_column(f / "imu.csv", "t", 1e3), error(2, "imu.csv")),
        orient("an imu column missing", lambda f: drop_column(f / "imu.csv", "gyr_z"), error(2, "imu.csv", "gyr_z")),
        orient("imu.csv empty", lambda f: (f / "imu.csv").write_text(""), error(2, "imu.csv")),
        orient("imu.csv missing", lambda f: (f / "imu.csv").unlink(), error(2, "imu.csv")),
        orient("a short gap (2 samples)", lambda f: gap(f, 2), warning("imu.csv"), accepted()),
        orient("a long gap (1 s)", lambda f: gap(f, 200), error(2, "imu.csv")),
        orient("imu rows out of order", lambda f: swap_rows(f / "imu.csv", 30, 31), error(2, "imu.csv", "'t'")),
        orient("imu rate_hz declared x3", lambda f: edit_yaml(f, imu={**yaml.safe_load((f / "session.yaml").read_text())["imu"],
                                                                    "rate_hz": 600.0}),
               error(2, "rate_hz"), warning("rate")),
        orient("--max-repair-s -1", lambda f: None, error(2, "--max-repair-s"), extra=("--max-repair-s", "-1")),
        broad("rest", "BROAD (real): a stationary recording, the trial's opening rest", lambda f: None, accepted(),
              warning("imu.csv")),
        broad("moving", "BROAD (real): 60 s of motion", lambda f: None, accepted()),
        broad("moving", "BROAD (real): gyro in deg/s",
              lambda f: scale_columns(f / "imu.csv", list(gyr), 180 / np.pi), error(2, "imu.csv", "deg/s")),
        broad("moving", "BROAD (real): accelerometer in g",
              lambda f: scale_columns(f / "imu.csv", list(acc), 1 / 9.80665), error(2, "imu.csv", "acc")),
        broad("rest", "BROAD (real): times in ms", lambda f: scale_column(f / "imu.csv", "t", 1e3), error(2, "imu.csv")),
    ]


def import_cases() -> list[Case]:
    def imp(name, fname, edit, *expect, extra=()):
        def make(work: Path, fx: Fixtures) -> list[str]:
            src = IMPORTERS / fname
            dst = work / fname
            shutil.copy(src, dst)
            edit(dst)
            return ["import", str(dst), "--out", str(work / "out"), *extra]
        return Case("import", name, make, tuple(expect), import_notes)

    def cut(p: Path) -> None:
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])

    return [
        imp("vicon: clean", "vicon_nexus.csv", lambda p: None, accepted()),
        imp("vicon: truncated half-way", "vicon_nexus.csv", cut, error(2, "vicon_nexus.csv"), accepted(), warning("vicon")),
        imp("vicon: --unit m for a mm export", "vicon_nexus.csv", lambda p: None, error(2, "--unit"), extra=("--unit", "m")),
        imp("qualisys: MARKER_NAMES missing", "qualisys_3d.tsv",
            lambda p: p.write_text("\n".join(ln for ln in p.read_text().splitlines() if not ln.startswith("MARKER_NAMES"))),
            error(2, "qualisys_3d.tsv", "MARKER_NAMES")),
        imp("motive: quaternion not unit", "motive.csv", _motive_not_unit, error(2, "motive.csv", "line", "quaternion")),
        imp("table: semicolons and decimal commas", "table_semicolon.csv", lambda p: None, accepted(), extra=("--unit", "mm")),
        imp("table: no --unit", "table_semicolon.csv", lambda p: None, error(2, "--unit")),
        imp("table: decimal commas in a comma-separated file", "table_semicolon.csv",
            lambda p: p.write_text(p.read_text().replace(";", ",")), error(2, "table_semicolon.csv"), extra=("--unit", "mm")),
        imp("empty file", "table_tab.tsv", lambda p: p.write_text(""), error(2, "table_tab.tsv")),
        imp("c3d: truncated", "c3d_rigid.c3d", cut, error(2, "c3d_rigid.c3d")),
        imp("not a recording (a YAML file)", "table_tab.tsv", lambda p: p.write_text("platform: stewart\n"),
            error(2, "table_tab.tsv")),
    ]


def _mimic_missing(urdf: Path) -> None:
    """arm_3_joint (on the arm's chain) made a mimic of a joint the URDF does not have."""
    tag = '<joint name="arm_3_joint" type="revolute">'
    replace_text(urdf, tag, tag + '<mimic joint="nosuch_joint" multiplier="1" offset="0"/>')


def _motive_not_unit(p: Path) -> None:
    lines = p.read_text().splitlines()
    # the first data row: its first rigid body's rotation cells (columns 2..5) doubled
    for k, ln in enumerate(lines):
        cells = ln.split(",")
        if cells and cells[0].strip().isdigit():
            for j in (2, 3, 4, 5):
                cells[j] = repr(2 * float(cells[j]))
            lines[k] = ",".join(cells)
            break
    p.write_text("\n".join(lines) + "\n")


def batch_cases() -> list[Case]:
    def batch(name, setup, *expect):
        def make(work: Path, fx: Fixtures) -> list[str]:
            return ["batch", *setup(work, fx), "--out", str(work / "out"), "--workers", "1", "--quiet"]
        return Case("batch", name, make, tuple(expect), batch_warnings)

    def fleet(edit_second):
        def setup(work: Path, fx: Fixtures) -> list[str]:
            fx.copy(fx.clean["rotary"], work / "fleet", "a")
            b = fx.copy(fx.clean["rotary"], work / "fleet", "b")
            edit_second(b)
            return ["calibrate", str(work / "fleet" / "*"), "--no-selection", "--no-report"]
        return setup

    return [
        batch("calibrate: one session past a limit within tolerance",
              fleet(lambda f: edit_cell(f / "commands.csv", 3, "u1", "181.8")), warning("'u1'", "past the limit")),
        batch("calibrate: one session with text in a cell", fleet(lambda f: edit_cell(f / "commands.csv", 2, "u1", "abc")),
              error(1, "commands.csv")),
        batch("calibrate: a pattern that matches nothing", lambda w, fx: ["calibrate", str(w / "none" / "*")],
              error(2, "none")),
    ]


def all_cases() -> list[Case]:
    return (session_cases() + body_cases() + method_cases() + tiago_cases() + predict_cases() + diagnose_cases() + fk_ik_cases()
            + simulate_cases() + plan_cases() + track_cases() + orient_cases() + import_cases() + batch_cases())


# ------------------------------------------------------------------ the sweep
def run_case(case: Case, fx: Fixtures, work: Path) -> Result:
    work.mkdir(parents=True)
    t0 = time.perf_counter()
    argv = case.make(work, fx)
    rc, out, err = run_cli(argv)
    written = None
    agrees = None
    if rc == 0:
        if case.outputs is not None:
            written = case.outputs(work, fx, out)
        if case.check is not None:
            try:
                agrees = case.check(work, fx, out)
            except Exception:  # noqa: BLE001  (the sweep's own reading of a written result)
                agrees = False
    klass, why = judge(case, rc, out, err, written, agrees)
    return Result(case, rc, klass, why, err.strip(), time.perf_counter() - t0)


def table(results: list[Result]) -> str:
    verbs = [v for v in VERBS if any(r.case.verb == v for r in results)]
    lines = [f"{'verb':10s}{'cases':>6s}" + "".join(f"{c:>14s}" for c in CLASSES)]
    for v in verbs + ["all"]:
        rs = [r for r in results if v in ("all", r.case.verb)]
        lines.append(f"{v:10s}{len(rs):6d}" + "".join(f"{sum(r.klass == c for r in rs):14d}" for c in CLASSES))
    return "\n".join(lines)


def main_(argv=None) -> int:
    warnings.simplefilter("ignore", PlatkitWarning)  # the verbs say theirs; the sweep's own readings are quiet
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--verbs", default=",".join(VERBS), help="comma-separated verbs (default all)")
    ap.add_argument("--only", default=None, help="run the cases whose name holds this text")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    ap.add_argument("--show", default="vague,SILENT-WRONG,TRACEBACK",
                    help="classes whose runs are printed one per line with their message (default: all but precise; 'all')")
    args = ap.parse_args(argv)
    verbs = set(args.verbs.split(","))
    cases = [c for c in all_cases() if c.verb in verbs and (args.only is None or args.only in c.name)]
    if args.list:
        for c in cases:
            print(f"{c.verb:10s} {c.name}")
        print(f"{len(cases)} cases")
        return 0
    show = set(CLASSES) if args.show == "all" else set(args.show.split(","))
    results = []
    with tempfile.TemporaryDirectory(prefix="platkit-sweep-") as tmp:
        root = Path(tmp)
        fx = build_fixtures(root / "fixtures", {c.verb for c in cases})
        # the real data are not beside the checkout: their cases cannot run, and are counted
        for data, needs in ((TIAGO, lambda c: "tiago" in c.name or c.verb == "track"),
                            (BROAD, lambda c: c.name.startswith("BROAD"))):
            skipped = [c for c in cases if needs(c)] if not data.is_dir() else []
            cases = [c for c in cases if c not in skipped]
            if skipped:
                print(f"{len(skipped)} cases skipped: they need {data} (the shared data beside the checkout)")
        for k, case in enumerate(cases):
            r = run_case(case, fx, root / f"case{k:03d}")
            results.append(r)
            if r.klass in show:
                last = r.err.splitlines()[-1] if r.err else ""
                print(f"{r.klass:12s} {case.verb:9s} {case.name}: {r.why} (exit {r.rc}) | {last[:400]}", flush=True)
    print()
    print(table(results))
    n_sw = sum(r.klass == "SILENT-WRONG" for r in results)
    n_tb = sum(r.klass == "TRACEBACK" for r in results)
    print(f"{len(results)} cases: silent wrong answers {n_sw} (goal 0), tracebacks {n_tb} (goal 0)")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
