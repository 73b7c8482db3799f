"""Bad inputs, as users have them, through the command line: counts of silent wrong answers and of
tracebacks (goal: 0 and 0).

Each case is a session (or commands file) made from a shipped example session with one thing
wrong, run through ``platkit calibrate`` (``--no-selection --no-report``: the fit, not the model
choice, is what a bad input spoils), ``platkit predict`` (with the clean session's calibration) or
``platkit diagnose`` (with the clean calibration), in-process through ``platkit.cli.main``.

Outcomes:
- refused: exit 2 (bad input) or 1 (failed computation) with one line;
- warned: exit 0 with at least one warning (stderr, and report.json's ``warnings`` for calibrate);
- fine: exit 0, no warning, and the result agrees with the clean run's (calibrate: the calibrated
  markers predicted on the clean commands within 3 times the clean fit's rms; predict: every
  predicted cell within 1e-6 of the clean prediction);
- SILENT WRONG: exit 0, no warning, and the result does not agree;
- TRACEBACK: an unexpected exception (the "run with --debug for the traceback" line).

Run:  .venv/bin/python benchmarks/bad_inputs_sweep.py [--only NAME,...] [--stands stewart,rotary]
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
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from platkit.calibrate.predict import prediction_table, read_commands  # noqa: E402
from platkit.cli import main  # noqa: E402
from platkit.io.calibration import read_calibration  # noqa: E402
from platkit.io.session import example_session  # noqa: E402
from platkit.model import length_scale  # noqa: E402
from platkit.notices import PlatkitWarning  # noqa: E402


# ------------------------------------------------------------------ editing a session's files
def _rows(path: Path) -> list[list[str]]:
    with path.open(newline="") as fh:
        return list(csv.reader(fh))


def _write(path: Path, rows: list[list[str]]) -> None:
    path.write_text("\n".join(",".join(r) for r in rows) + "\n")


def _scale_column(path: Path, col: str, k: float) -> None:
    rows = _rows(path)
    j = rows[0].index(col)
    for r in rows[1:]:
        if r[j]:
            r[j] = f"{float(r[j]) * k:.9g}"
    _write(path, rows)


def _scale_columns(path: Path, suffixes: tuple[str, ...], k: float) -> None:
    rows = _rows(path)
    for j, name in enumerate(rows[0]):
        if name.endswith(suffixes):
            for r in rows[1:]:
                if r[j]:
                    r[j] = f"{float(r[j]) * k:.9g}"
    _write(path, rows)


def _yaml(folder: Path, old: str, new: str) -> None:
    y = (folder / "session.yaml").read_text()
    if old not in y:
        raise SystemExit(f"case needs {old!r} in {folder / 'session.yaml'}")
    (folder / "session.yaml").write_text(y.replace(old, new, 1))


def _swap_headers(path: Path, a: str, b: str) -> None:
    rows = _rows(path)
    i, j = rows[0].index(a), rows[0].index(b)
    rows[0][i], rows[0][j] = b, a
    _write(path, rows)


def _edit_cell(path: Path, row: int, col: str, value: str) -> None:
    rows = _rows(path)
    rows[row][rows[0].index(col)] = value
    _write(path, rows)


def _control_past(path: Path, spec_upper: float, stroke: float, share: float, col: str) -> None:
    _edit_cell(path, 3, col, f"{spec_upper + share * stroke:.9g}")


def _cut_line(path: Path) -> None:
    rows = _rows(path)
    rows[5] = rows[5][:-2]
    _write(path, rows)


def _shift_marker(path: Path, marker: str, mm: float) -> None:
    rows = _rows(path)
    j = rows[0].index(f"{marker}_x")
    for r in rows[len(rows) // 2:]:
        if r[j]:
            r[j] = f"{float(r[j]) + mm:.6f}"
    _write(path, rows)


def _semicolons(path: Path) -> None:
    path.write_text(path.read_text().replace(",", ";"))


def _duplicate_time(path: Path) -> None:
    rows = _rows(path)
    rows[4][0] = rows[3][0]
    _write(path, rows)


def _rate_times_5(folder: Path) -> None:
    import yaml

    y = yaml.safe_load((folder / "session.yaml").read_text())
    y["mocap_rate_hz"] = 5 * float(y["mocap_rate_hz"])
    (folder / "session.yaml").write_text(yaml.safe_dump(y))


def _drop_file(path: Path) -> None:
    path.unlink()


#: session cases: name -> (what it does to the folder, stands it applies to)
def session_cases(stand: str, spec) -> dict:
    c0 = spec.controls[0]
    unit_k = 1e3 if c0.unit == "m" else 1.0  # the example files write 'm' controls in mm
    first = spec.control_names[0]
    markers = example_markers(stand)
    m0, m1 = markers[0], markers[1]
    return {
        "times in ms declared s": lambda f: (_scale_column(f / "markers.csv", "t", 1e3),
                                             _scale_column(f / "commands.csv", "t", 1e3)),
        "times in s declared ms": lambda f: _yaml(f, "time: s", "time: ms"),
        "mocap_rate_hz wrong (x5)": _rate_times_5,
        "command log in ms, stream in s": lambda f: _scale_column(f / "commands.csv", "t", 1e3),
        "markers in m declared mm": lambda f: _scale_columns(f / "markers.csv", ("_x", "_y", "_z"), 1e-3),
        "markers in um declared mm": lambda f: _scale_columns(f / "markers.csv", ("_x", "_y", "_z"), 1e3),
        "length unit declared m": lambda f: _yaml(f, "length: mm", "length: m"),
        "marker columns swapped (x of two markers)": lambda f: _swap_headers(f / "markers.csv", f"{m0}_x", f"{m1}_x"),
        "a marker slips 5 mm half-way": lambda f: _shift_marker(f / "markers.csv", m0, 5.0),
        "control 0.5% past its limit": lambda f: _control_past(f / "commands.csv", c0.upper * unit_k,
                                                               (c0.upper - c0.lower) * unit_k, 0.005, first),
        "control 5% past its limit": lambda f: _control_past(f / "commands.csv", c0.upper * unit_k,
                                                             (c0.upper - c0.lower) * unit_k, 0.05, first),
        "control in the other length unit": lambda f: _scale_column(f / "commands.csv", first, 1e-3 if unit_k > 1 else 1.0),
        "text in a control cell": lambda f: _edit_cell(f / "commands.csv", 2, first, "abc"),
        "empty control cell": lambda f: _edit_cell(f / "commands.csv", 2, first, ""),
        "cut line in markers.csv": lambda f: _cut_line(f / "markers.csv"),
        "duplicated timestamp": lambda f: _duplicate_time(f / "markers.csv"),
        "semicolon separator": lambda f: _semicolons(f / "commands.csv"),
        "commands.csv missing": lambda f: _drop_file(f / "commands.csv"),
        "markers.csv missing": lambda f: _drop_file(f / "markers.csv"),
        "undeclared marker column": lambda f: _yaml(f, f"- {m1}\n", ""),
        "unknown platform": lambda f: _yaml(f, f"platform: {stand}", "platform: nosuch"),
    }


def example_markers(stand: str) -> list[str]:
    import yaml

    return list(yaml.safe_load((example_session(stand) / "session.yaml").read_text())["markers"])


# ------------------------------------------------------------------ running and judging
def run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def predicted_markers_m(cal_path: Path, commands: Path) -> np.ndarray:
    """The markers (N, 3 M) m that a calibration predicts for a commands file (the sweep's own
    reading, outside any verb: the warnings it meets were said by the verb already)."""
    cal = read_calibration(cal_path)
    U, t = read_commands(commands, cal)
    header, rows, ok = prediction_table(cal, U, t)
    cols = [i for i, h in enumerate(header) if h.endswith(("_x", "_y", "_z")) and h[:-2] in cal.marker_names]
    return rows[:, cols] * length_scale(cal.length_unit)


def judge(rc: int, err: str, warnings: list[str], agrees: bool | None) -> str:
    if "run with --debug for the traceback" in err or "Traceback" in err:
        return "TRACEBACK"
    if rc != 0:
        return "refused"
    if warnings or "platkit: warning:" in err:
        return "warned"
    return "fine" if agrees in (True, None) else "SILENT WRONG"


def sweep(stands: list[str], only: set[str] | None) -> list[tuple[str, str, str, str]]:
    from platkit.plugins import get_platform

    results = []
    with tempfile.TemporaryDirectory(prefix="platkit-sweep-") as tmp:
        tmp = Path(tmp)
        for stand in stands:
            spec = get_platform(stand)
            clean = tmp / stand / "clean"
            shutil.copytree(example_session(stand), clean)
            rc, _, err = run_cli(["calibrate", str(clean), "--out", str(tmp / stand / "clean_cal"), "--no-selection",
                                  "--no-report", "--quiet"])
            if rc:
                raise SystemExit(f"the clean {stand} example does not calibrate: {err}")
            clean_cal = tmp / stand / "clean_cal" / "calibration.yaml"
            clean_rms = json.loads((tmp / stand / "clean_cal" / "report.json").read_text())["rms_after"]
            clean_rms_m = clean_rms * length_scale(read_calibration(clean_cal).length_unit)
            reference = predicted_markers_m(clean_cal, clean / "commands.csv")
            for name, make in session_cases(stand, spec).items():
                if only and name not in only:
                    continue
                folder = tmp / stand / f"case{len(results)}"
                shutil.copytree(clean, folder)
                make(folder)
                # calibrate
                out = folder.with_name(folder.name + "_cal")
                rc, _, err = run_cli(["calibrate", str(folder), "--out", str(out), "--no-selection", "--no-report",
                                      "--quiet"])
                warnings, agrees = [], None
                if rc == 0:
                    warnings = json.loads((out / "report.json").read_text())["warnings"]
                    got = predicted_markers_m(out / "calibration.yaml", clean / "commands.csv")
                    d = np.sqrt(np.nanmean(np.sum((got - reference).reshape(len(got), -1, 3) ** 2, axis=2)))
                    agrees = bool(d <= 3 * clean_rms_m)
                results.append((stand, name, "calibrate", judge(rc, err, warnings, agrees), err.strip()[-160:]))
                # predict: the case's commands with the clean calibration
                if (folder / "commands.csv").is_file():
                    pred = folder.with_name(folder.name + "_pred.csv")
                    rc, _, err = run_cli(["predict", "--calibration", str(clean_cal), "--commands",
                                          str(folder / "commands.csv"), "--out", str(pred)])
                    agrees = None
                    if rc == 0:
                        try:
                            got = predicted_markers_m(clean_cal, folder / "commands.csv")
                            agrees = got.shape == reference.shape and bool(np.nanmax(np.abs(got - reference)) < 1e-6)
                        except Exception:  # noqa: BLE001  (the sweep's own reading: not the verb's)
                            agrees = False
                    results.append((stand, name, "predict", judge(rc, err, [], agrees), err.strip()[-160:]))
    return results


def main_(argv=None) -> int:
    warnings.simplefilter("ignore", PlatkitWarning)  # the verbs print theirs; the sweep's own readings are quiet
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stands", default="stewart,rotary")
    ap.add_argument("--only", default=None, help="comma-separated case names")
    args = ap.parse_args(argv)
    only = set(args.only.split(",")) if args.only else None
    results = sweep(args.stands.split(","), only)
    width = max(len(r[1]) for r in results)
    for stand, name, verb, outcome, err in results:
        print(f"{stand:8s} {name:{width}s} {verb:9s} {outcome:12s} {err.splitlines()[-1][:110] if err else ''}")
    counts = {k: sum(r[3] == k for r in results) for k in ("refused", "warned", "fine", "SILENT WRONG", "TRACEBACK")}
    print(f"{len(results)} runs: " + ", ".join(f"{v} {k}" for k, v in counts.items()))
    print(f"silent wrong answers {counts['SILENT WRONG']} (goal 0), tracebacks {counts['TRACEBACK']} (goal 0)")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
