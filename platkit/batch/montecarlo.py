"""Monte-Carlo evaluation of command plans (``platkit plan --monte-carlo N``).

Draw d (seed ``seed + d``) is one plausible true stand around the description (parameters
perturbed as platkit.simulate does: 2 mm, 2 mrad per parameter), with the plan's marker layout,
a random motion-capture frame and any hidden effects; the plan is simulated on it (settled
poses, the given marker noise), calibrated with platkit's estimator (as ``platkit calibrate``
does by default), and scored on the stand's reference poses (platkit.calibrate.plan.
reference_poses: the same held-out poses for every plan and draw), noise-free:

    held-out error = RMS over reference poses and markers of |predicted - true marker position|

in the motion-capture frame (gauge-free), and each parameter's error (estimate - truth; NaN
where the data could not fix it and it was held at nominal). Every plan sees the same true
stands (common random numbers), so plans compare draw by draw. A draw is one Dask task.
"""
from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

import numpy as np

from platkit.batch.engine import Outcome, Task, cluster, run_tasks
from platkit.batch.store import BatchFolder
from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.calibrate.plan import marker_links, reference_poses
from platkit.errors import ComputationFailed
from platkit.io.jsonout import dumps
from platkit.plugins import get_platform
from platkit.simulate import simulate

__all__ = ["draw", "draw_seed", "evaluate_plans", "summarise_draws", "paired_wins"]

HOLD_S = 1.5


@functools.lru_cache(maxsize=8)
def _spec(platform: str, description: str | None, options: tuple):
    """The stand of ``options`` as :func:`options_key` made it hashable (a tree's moving_link
    mapping as its pairs)."""
    return get_platform(platform, description, **{k: dict(v) if isinstance(v, tuple) else v for k, v in options})


def options_key(options: dict) -> tuple:
    """The stand options as a hashable key (sorted items; a mapping, a tree's moving_link, as its
    pairs): what :func:`draw` is given."""
    return tuple(sorted((k, tuple(v.items()) if isinstance(v, dict) else v) for k, v in options.items()))


def draw(platform: str, description: str | None, options: tuple, controls: np.ndarray, markers: np.ndarray,
         seed: int, noise_mm: float, effects: tuple = ()) -> dict:
    """One Monte-Carlo draw (runs on a worker). ``controls`` (N, n_u) internal units, the plan;
    ``markers`` (M, 3) m, the marker layout on the moving part; ``effects`` ((name, size), ...).
    Returns heldout_rms_m, fit_rms_m, converged, parameter_error (n_td,) (SI; NaN where held),
    parameter names, and the truth's seed; on a tree (markers on tracked link k mod L, as plan
    places them) also heldout_rms_m_links, the held-out error over each link's markers."""
    spec = _spec(platform, description, options)
    # one motion-capture sample per settled pose (rate 2 / hold): noise_mm is then a settled pose's noise
    common = dict(seed=seed, raw=False, occlusion=0.0, n_markers=len(markers), markers=np.asarray(markers, float),
                  effects=list(effects), hold_s=HOLD_S, mocap_rate_hz=2.0 / HOLD_S)
    sim = simulate(spec, plan=np.asarray(controls, float), n_poses=len(controls), noise_mm=noise_mm, **common)
    ref_controls = reference_poses(spec).controls
    ref = simulate(spec, plan=ref_controls, n_poses=len(ref_controls), noise_mm=0.0, **common)
    for a, b, what in ((sim.truth.td, ref.truth.td, "parameters"),
                       (sim.truth.mocap_from_base, ref.truth.mocap_from_base, "motion-capture frame"),
                       (sim.truth.markers, ref.truth.markers, "markers")):
        if not np.allclose(a, b, rtol=0, atol=1e-12):
            raise ComputationFailed(f"draw {seed}: the held-out simulation drew another true stand ({what}); "
                                    "platkit.simulate no longer draws the truth before the plan's noise")
    cal = calibrate(sim.poses, spec)
    predicted, _, _, ok = predict_markers(cal, ref_controls, ref.poses)
    err = np.linalg.norm(predicted - ref.poses.markers, axis=2)[np.asarray(ok, bool)]
    estimated = np.array([st == "estimated" for st in cal.td_status])
    perr = np.where(estimated, cal.td - sim.truth.td, np.nan)
    out = {"seed": int(seed), "heldout_rms_m": float(np.sqrt(np.mean(err ** 2))) if err.size else float("nan"),
           "heldout_poses": int(np.sum(ok)), "fit_rms_m": float(cal.rms_after), "converged": bool(cal.converged),
           "parameter_error": perr.tolist(), "parameter_names": [p.name for p in spec.parameters]}
    links = np.array(marker_links(spec, len(markers)))
    if len(set(links)) > 1:
        out["heldout_rms_m_links"] = {str(k): float(np.sqrt(np.mean(err[:, links == k] ** 2))) if err.size else float("nan")
                                      for k in dict.fromkeys(links)}
    return out


def summarise_draws(results: list[dict], units: list[str]) -> dict:
    """Distribution over draws: held-out RMS (mm) quantiles, and per parameter the RMS and 95th
    percentile of |error| (mm or mrad for lengths and angles, else the parameter's unit)."""
    h = np.array([r["heldout_rms_m"] for r in results], float) * 1e3
    out = {"n_draws": len(results), "n_converged": int(sum(r["converged"] for r in results)),
           "heldout_rms_mm": {"mean": float(np.nanmean(h)), "median": float(np.nanmedian(h)),
                              "p90": float(np.nanpercentile(h, 90)), "p95": float(np.nanpercentile(h, 95)),
                              "max": float(np.nanmax(h))},
           "parameter_error": {}}
    if "heldout_rms_m_links" in results[0]:  # a tree: the same quantiles over each tracked link's markers
        out["heldout_rms_mm_links"] = {}
        for link in results[0]["heldout_rms_m_links"]:
            h_l = np.array([r["heldout_rms_m_links"][link] for r in results], float) * 1e3
            out["heldout_rms_mm_links"][link] = {"mean": float(np.nanmean(h_l)), "median": float(np.nanmedian(h_l)),
                                                 "p90": float(np.nanpercentile(h_l, 90)), "max": float(np.nanmax(h_l))}
    E = np.array([r["parameter_error"] for r in results], float)
    for j, name in enumerate(results[0]["parameter_names"]):
        e = E[:, j]
        seen = e[np.isfinite(e)]
        scale, unit = (1e3, "mm") if units[j] == "m" else (1e3, "mrad") if units[j] == "rad" else (1.0, units[j])
        out["parameter_error"][name] = {
            "unit": unit, "n_estimated": int(seen.size),
            "rms": float(np.sqrt(np.mean(seen ** 2)) * scale) if seen.size else None,
            "p95_abs": float(np.percentile(np.abs(seen), 95) * scale) if seen.size else None}
    return out


def paired_wins(a: list[dict], b: list[dict]) -> float:
    """Fraction of the draws (same seeds) in which plan a's held-out error is below plan b's."""
    ha = {r["seed"]: r["heldout_rms_m"] for r in a}
    hb = {r["seed"]: r["heldout_rms_m"] for r in b}
    seeds = sorted(set(ha) & set(hb))
    return float(np.mean([ha[s] < hb[s] for s in seeds])) if seeds else float("nan")


def draw_seed(seed: int, d: int) -> int:
    """The simulation seed of draw ``d`` of a study with --seed ``seed`` (the same for every plan)."""
    return 1_000_000 * (1 + int(seed)) + int(d)


def evaluate_plans(platform: str, description: str | None, options: dict, plans: dict[str, np.ndarray],
                   markers: np.ndarray, n_draws: int, noise_mm: float, effects=(), seed: int = 0,
                   folder: str | Path = "montecarlo", scheduler: str | None = None, workers: int | None = None,
                   progress=None) -> dict:
    """Run ``n_draws`` draws of every plan (``{name: controls (N, n_u)}``, internal units) as Dask
    tasks, each draw's result written to ``folder``/draws/<plan>__draw<d>/draw.json as it finishes
    (a re-run skips the draws there); return ``{name: summary}`` (summarise_draws, plus n_poses,
    the draws and, for every other plan, the fraction of draws this one beats it in)."""
    spec = _spec(platform, description, options_key(options))
    units = [p.unit for p in spec.parameters]
    record = {"platform": platform, "description": description, "options": options, "noise_mm": noise_mm,
              "effects": [list(e) for e in effects], "seed": seed,
              "markers_m": np.asarray(markers, float).round(12).tolist(),
              "plans": {k: hashlib.sha256(np.ascontiguousarray(v, float).tobytes()).hexdigest()[:16]
                        for k, v in plans.items()}}
    store = BatchFolder(folder, "plan --monte-carlo", record, items="draws")
    key = {(name, d): f"{name}__draw{d:05d}" for name in plans for d in range(n_draws)}
    todo = [Task(k, (platform, description, options_key(options), plans[name], np.asarray(markers, float),
                     draw_seed(seed, d), noise_mm, tuple(effects)))
            for (name, d), k in key.items() if not store.done(k)]

    def keep(outcome: Outcome) -> None:
        if outcome.ok:
            store.write_session(outcome.key, {"draw.json": (dumps(outcome.value) + "\n").encode()},
                                {"ok": True, "seconds": outcome.seconds, "worker": outcome.worker})
        else:
            store.write_failure(outcome.key, {"ok": False, "error": outcome.error, "kind": outcome.kind})

    failed = []
    if todo:
        with cluster(scheduler, workers) as client:
            failed = [o for o in run_tasks(client, draw, todo, on_outcome=keep, progress=progress) if not o.ok]
    if failed:
        raise ComputationFailed(f"{len(failed)} of {len(key)} Monte-Carlo draws failed (first: {failed[0].key}: "
                                f"{failed[0].error}); listed in {store.failed}; run again to retry them")
    store.start()
    results = {name: [json.loads((store.sessions / key[(name, d)] / "draw.json").read_text(encoding="utf-8"))
                      for d in range(n_draws)] for name in plans}
    out = {}
    for name, rs in results.items():
        out[name] = {"n_poses": int(len(plans[name])), **summarise_draws(rs, units),
                     "beats": {other: paired_wins(rs, results[other]) for other in plans if other != name},
                     "draws": [{"seed": r["seed"], "heldout_rms_mm": r["heldout_rms_m"] * 1e3,
                                "fit_rms_mm": r["fit_rms_m"] * 1e3, "converged": r["converged"]} for r in rs]}
    return out
