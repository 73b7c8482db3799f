"""A streamed session cut in time into two sessions of the same stand: the training part (the
commands and motion-capture samples before the cut) and the held-out part (those from it on), each
with the session's session.yaml and files beside (shared by the tests and benchmarks of held-out
streams: the two parts share the stand's truth, not its samples); and a simulated stream written
and read back (:func:`written_stream`)."""
from __future__ import annotations

import csv
import shutil
from pathlib import Path

from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def written_stream(folder: Path, seed: int, duration_s: float, motion: str = "multisine", rate_hz: float = 50.0):
    """A Stewart stream of the physical simulator (``seed``, ``motion`` for ``duration_s`` s, the
    motion capture at ``rate_hz``) written to ``folder`` and read back: (the simulation, the
    session)."""
    sim = simulate_physics(get_platform("stewart"), seed=seed, motion=motion, duration_s=duration_s,
                           mocap_rate_hz=rate_hz)
    write_physical_session(sim, folder)
    return sim, load_session(folder)


def split_stream(src: Path, out: Path, share: float, lead_s: float = 2.0,
                 log_cut_s: float = 0.0) -> tuple[Path, Path]:
    """``src`` cut at ``share`` of its command log's span into ``out / 'train'`` (before the cut)
    and ``out / 'heldout'`` (from the cut on): markers.csv and commands.csv split by their time
    column, every other file copied; the held-out command log starts ``lead_s`` before its first
    marker sample (a log that began before the recording: the response model starts the actuators
    at rest on the first command, and the stand, cut from a stream, is moving at the cut); the
    training command log ends ``log_cut_s`` before the cut, its markers running on to it (a log
    that stops while the stand moves). Returns (train, heldout)."""
    rows = list(csv.reader((src / "markers.csv").open()))
    cmds = list(csv.reader((src / "commands.csv").open()))
    t0, t1 = float(cmds[1][0]), float(cmds[-1][0])
    cut = t0 + share * (t1 - t0)
    parts = []
    for part, keep, keep_cmd in (("train", lambda t: t < cut, lambda t: t < cut - log_cut_s),
                                 ("heldout", lambda t: t >= cut, lambda t: t >= cut - lead_s)):
        dst = out / part
        shutil.copytree(src, dst)
        for name, table, rule in (("markers.csv", rows, keep), ("commands.csv", cmds, keep_cmd)):
            with (dst / name).open("w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(table[0])
                w.writerows(r for r in table[1:] if rule(float(r[0])))
        parts.append(dst)
    return parts[0], parts[1]


def settled_commands(session: Path, controls: list[str], out: Path, t_from: float = float("-inf")) -> list[dict]:
    """The commands of ``session``'s truth_settled.csv (each command where the true stand settles)
    from time ``t_from`` on, written to ``out`` as a command log (t and ``controls``) that
    ``platkit predict`` reads; returns those truth rows."""
    rows = [r for r in csv.DictReader((session / "truth_settled.csv").open()) if float(r["t"]) >= t_from]
    with out.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", *controls])
        w.writerows([r["t"], *(r[c] for c in controls)] for r in rows)
    return rows


def settled_error_mm(rows: list[dict], predicted: Path, markers: list[str]) -> float:
    """RMS (3-D, the file's length unit) of the markers ``predict`` wrote to ``predicted`` against
    the true settled ones of ``rows`` (:func:`settled_commands`), row by row."""
    got = list(csv.DictReader(predicted.open()))
    e = [[float(g[f"{m}_{c}"]) - float(r[f"{m}_{c}"]) for c in "xyz"] for g, r in zip(got, rows) for m in markers]
    return float(sum(sum(x * x for x in p) for p in e) / len(e)) ** 0.5
