"""platkit calibrate: estimate a stand's parameters from a recording session."""
from __future__ import annotations

import math
import sys
from pathlib import Path

from platkit.errors import BadInput, ComputationFailed
from platkit.io.atomic import check_output_dir
from platkit.model import length_scale
from platkit.notices import said, warn


def add_parser(sub):
    p = sub.add_parser("calibrate", help="estimate a stand's parameters from a session (calibration.yaml, report)")
    p.add_argument("session", nargs="?", default=None,
                   help="session folder (default with --platform: the example session shipped for that stand)")
    p.add_argument("--platform", default=None, help="stand name (default: the session's)")
    p.add_argument("--description", default=None, help="description file (default: the session's, else the stand's)")
    p.add_argument("--method", choices=["lsq", "paper"], default="lsq",
                   help="lsq: one robust least-squares problem with exact Jacobians (default); "
                        "paper: Burlakov et al. 2018 (Procrustes, FK, q_delta, Nelder-Mead)")
    p.add_argument("--free", default=None,
                   help="comma-separated parameter names or groups to fit, and no selection (default: the groups "
                        "chosen by held-out prediction); 'none' fits only the base-to-mocap transform and the markers")
    p.add_argument("--no-selection", action="store_true",
                   help="fit the stand's default free parameters instead of choosing the groups by held-out prediction")
    p.add_argument("--prior-strength", type=float, default=None, metavar="LENGTH",
                   help="shrink the stand's parameters towards nominal: one typical correction (1 mm, 1 mrad, 1e-3) "
                        "costs as much as a marker error of LENGTH (session unit); default none")
    p.add_argument("--folds", type=int, default=0, help="K-fold held-out prediction error (K >= 2; default none)")
    p.add_argument("--validate", default=None, metavar="SESSION",
                   help="a second session in the same motion-capture frame to predict (held-out error)")
    p.add_argument("--max-evaluations", type=int, default=None,
                   help="--method paper: Nelder-Mead budget (default 200 per parameter)")
    p.add_argument("--no-robust", action="store_true", help="plain least squares (no outlier down-weighting)")
    p.add_argument("--response", default=None, metavar="PARTS",
                   help="where the stand is calibrated from motion (holds that do not settle, or none): add to the "
                        "actuators' response, comma-separated, 'delays' (each actuator's own pure delay beyond the "
                        "common shift) and 'rate-limit' (a streamed drive's speed limit, fitted)")
    p.add_argument("--response-kind", default="auto", type=lambda x: x.replace("_", "-"),
                   choices=["auto", "first-order", "second-order"],
                   help="where the stand is calibrated from motion: the actuators' response, 'first-order' (a lag), "
                        "'second-order' (time constant and damping), or 'auto' (default: the second order for the "
                        "actuators whose data determine it and where it fits better by BIC, the first otherwise)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--no-report", action="store_true",
                   help="write calibration.yaml and report.json only, not report.html (its figures take longer "
                        "than a small calibration)")
    p.add_argument("--out", required=True, help="output folder (calibration.yaml, report.json, report.html)")
    return p


def progress_printer(unit: str, stream=None):
    """A progress callback that prints one line per event to ``stream`` (default: stderr)."""
    s = length_scale(unit)

    def show(stage: str, info: dict) -> None:
        out = stream if stream is not None else sys.stderr
        if stage in ("registration", "iteration"):
            print(f"calibrate: {'registration' if stage == 'registration' else 'fit':<12} iteration {info['iteration']:>3}  rms {info['rms'] / s:.4g} {unit}",
                  file=out, flush=True)
        elif stage == "identifiability":
            held = info.get("held") or []
            print(f"calibrate: {info['n_identifiable']} unknowns identifiable; held at nominal: "
                  f"{', '.join(held) if held else 'none'}", file=out, flush=True)
        elif stage == "fold":
            print(f"calibrate: fold {info['fold']}/{info['folds']}  held-out rms {info['rms'] / s:.4g} {unit}",
                  file=out, flush=True)
        elif stage == "selection":
            print(f"calibrate: selection: {info['text']}", file=out, flush=True)
        elif stage == "paper":
            print(f"calibrate: nelder-mead evaluation {info['evaluations']:>5}  J {info['J']:.6g}",
                  file=out, flush=True)
        elif stage == "done":
            print(f"calibrate: rms {info['rms_before'] / s:.4g} -> {info['rms_after'] / s:.4g} {unit} "
                  f"in {info['time_s']:.2f} s", file=out, flush=True)

    return show


#: the actuators' response of a calibration from motion, as a progress line names it
KIND_WORDS = {"first_order": "first-order response", "second_order": "second-order response",
              "per_actuator": "second-order response for some actuators"}


def motion_progress_printer(unit: str, kind: str, stream=None):
    """:func:`progress_printer` for a calibration from motion (platkit.calibrate.motion), which fits
    the stream several times: a first line says so, and each fit is numbered and said with the
    response's kind it fits, its "rms a -> b" from that fit's own start (a later fit may start worse
    than an earlier one ended). ``kind``: as asked ('auto', 'first_order', 'second_order'), said in
    the first line; each fit's own kind is the one its events say (``response_kind``, as
    :func:`platkit.calibrate.motion_kind.fit_progress` tells it: 'first_order', 'second_order' or
    'per_actuator'), the kind asked where an event says none."""
    show = progress_printer(unit, stream)
    s = length_scale(unit)
    state: dict = {"fit": 0, "label": KIND_WORDS.get(kind, kind)}
    plan = ("first order, then second order tried from it (from more than one start; kept by BIC where "
            "determined: report motion.response.choice)" if kind == "auto" else KIND_WORDS.get(kind, kind))

    def show_motion(stage: str, info: dict) -> None:
        out = stream if stream is not None else sys.stderr
        if state["fit"] == 0:
            print(f"calibrate: from motion: the actuators' response fitted {plan}; each fit numbered below, its rms "
                  "from its own start", file=out, flush=True)
            state["fit"] = 1
        if stage == "identifiability":
            said = info.get("response_kind", kind)
            state["label"] = KIND_WORDS.get(said, said)
            held = info.get("held") or []
            print(f"calibrate: fit {state['fit']} ({state['label']}): {info['n_identifiable']} unknowns identifiable; "
                  f"held at nominal: {', '.join(held) if held else 'none'}", file=out, flush=True)
        elif stage == "done":
            print(f"calibrate: fit {state['fit']} ({state['label']}) rms {info['rms_before'] / s:.4g} -> "
                  f"{info['rms_after'] / s:.4g} {unit} from its own start, in {info['time_s']:.2f} s",
                  file=out, flush=True)
            state["fit"] += 1
        else:
            show(stage, info)

    return show_motion


def load_for_calibration(session: str | None, platform: str | None, description: str | None, quiet: bool = False,
                         notes: list[str] | None = None, stream_if_extrapolated: bool = False):
    """(poses, spec, platform_options) of a session folder, or of the stand's example session.
    The folder's streams are read once; ``quiet``: no reading progress on stderr. What the reading
    kept with a warning is said on stderr and appended to ``notes``. ``stream_if_extrapolated``:
    HoldsNeverSettle where holds were extrapolated to rest (:func:`refuse_extrapolated_holds`)."""
    s = read_session(session, platform, description, quiet)
    poses, found = settled_poses(s)
    if stream_if_extrapolated:
        refuse_extrapolated_holds(poses, s.folder)
    say_reading(s, found, notes)
    return poses, s.spec, platform_options(s)


def read_session(session: str | None, platform: str | None, description: str | None, quiet: bool = False):
    """The session folder ``session`` read (platkit.io.session.Session), or the stand's example
    session where none is given; ``quiet``: no reading progress on stderr."""
    from platkit.io.session import example_session, load_session

    if session is None:
        if platform is None:
            raise BadInput("give a SESSION folder, or --platform NAME to run on that stand's example session")
        session = example_session(platform)
    return load_session(Path(session), platform=platform, description=description, quiet=quiet)


def settled_poses(s) -> tuple:
    """(poses, notes) of the read session ``s``: its settled poses and what settling dropped and
    extrapolated, one line each (:func:`settling_notes`, which refuses a remnant)."""
    from platkit.settle import load_poses

    poses = load_poses(s.folder, spec=s.spec, session=s)
    return poses, settling_notes(poses, s.folder)


def platform_options(s) -> dict:
    """The stand's options a session carries (a tree's ``moving_link``)."""
    return {"moving_link": s.moving_link} if s.moving_link else {}


def say_reading(s, found: list[str], notes: list[str] | None) -> None:
    """Say what the reading of ``s`` kept with a warning and what settling ``found``, each on
    stderr and once in ``notes``."""
    for note in s.extras.get("control_notes", []) + found:  # kept with a warning
        warn(note)
        if notes is not None and note not in notes:
            notes.append(note)


def settling_notes(poses, folder) -> list[str]:
    """What settling dropped (counted by reason) and extrapolated, one line each; ComputationFailed
    when fewer than half the commands gave a pose (a fit to the remnant would look converged)."""
    from platkit.errors import ComputationFailed
    from platkit.settle import HoldsNeverSettle, dropped_sentence, refusal

    info = poses.settling or {}
    n_commands = int(info.get("n_commands", poses.n_poses + len(poses.dropped)))
    said = dropped_sentence(poses.dropped, n_commands)
    if poses.n_poses < 0.5 * n_commands:
        # holds that did not settle: the motion model may serve (platkit calibrate); commands without
        # samples: no model does
        unsampled = sum(1 for _, why in poses.dropped if str(why).startswith("no motion-capture samples"))
        text = (f"{folder}: {said}; a calibration from the {poses.n_poses} left would fit a remnant of the "
                "session: see the reasons (platkit calibrate counts them) and record again")
        if unsampled >= 0.5 * len(poses.dropped):
            raise ComputationFailed(text)
        n_settled = poses.n_poses - int(info.get("n_extrapolated", 0))
        raise HoldsNeverSettle(text, refusal(f"only {poses.n_poses} of {n_commands} commands gave a pose, under half "
                                             f"({said})", info.get("unsettled") or {}, n_commands, n_settled))
    out = [said] if said else []
    un = info.get("unsettled") or {}
    if info.get("n_extrapolated"):
        out.append(f"{un.get('sentence', 'holds never settled')}; {info['n_extrapolated']} of them extrapolated to "
                   "rest from their approach (weighted by its uncertainty)")
    elif un:
        out.append(un["sentence"])
    return out


def refuse_extrapolated_holds(poses, folder) -> None:
    """HoldsNeverSettle wherever a hold was extrapolated to rest, however many settled: the raw
    stream is there, so it is the data (a calibration from motion, diagnosed on the stream's
    windows) rather than poses of which the extrapolated carry what the approach model missed
    along the slow actuator's last move. A session none of whose holds was extrapolated keeps its
    poses. The reason says whether the settled were under what diagnosis needs to judge the stand's
    physics on (platkit.diagnose.search.settled_needed at its default folds)."""
    from platkit.diagnose.search import settled_needed
    from platkit.settle import HoldsNeverSettle, refusal

    info = poses.settling or {}
    n_extrapolated = int(info.get("n_extrapolated", 0))
    if not n_extrapolated:
        return
    n_settled = poses.n_poses - n_extrapolated
    need = settled_needed()
    n_commands = int(info.get("n_commands", poses.n_poses + len(poses.dropped)))
    under = (f"under the {need} settled poses diagnosis judges the stand's physics on" if n_settled < need
             else "the extrapolated poses carry what the approach model missed: the stream is the data")
    reason = f"{n_settled} of {n_commands} holds settled, {n_extrapolated} extrapolated to rest: {under}"
    raise HoldsNeverSettle(f"{folder}: {reason}", refusal(reason, info.get("unsettled") or {}, n_commands, n_settled,
                                                         n_extrapolated=n_extrapolated, settled_needed=need,
                                                         poses_usable=True))


def run(args) -> int:
    from platkit.calibrate.report import write_outputs

    if args.folds and args.folds < 2:
        raise BadInput(f"--folds {args.folds}: use 2 or more (or leave it out)")
    if args.folds and args.method == "paper":
        raise BadInput("--folds applies to --method lsq; use --validate SESSION to score the paper's method")
    if args.max_evaluations is not None and args.method != "paper":
        raise BadInput("--max-evaluations applies to --method paper")
    if args.method == "paper" and (args.no_selection or args.prior_strength is not None):
        raise BadInput("--no-selection and --prior-strength apply to --method lsq")
    if args.free is not None and args.no_selection:
        raise BadInput("--free already fits the groups named, without selection: leave out --no-selection")
    if args.prior_strength is not None and not (args.prior_strength > 0 and math.isfinite(args.prior_strength)):
        raise BadInput(f"--prior-strength {args.prior_strength}: use a positive length in the session's unit")
    response = getattr(args, "response", None)  # a batch's options stored before the flag lack it
    response_parts(response)  # bad parts are bad input before any work
    check_output_dir(args.out)
    notes: list[str] = []
    from platkit.settle import HoldsNeverSettle, NeverSettles

    s = read_session(args.session, args.platform, args.description, quiet=args.quiet)  # read once, whatever follows
    # read once, before any work: a bad one is bad input, found at once; none for an IMU-only session
    # (no stand: settled_poses refuses it in one line)
    other = None if s.spec is None else second_session(args, s.spec.name)
    read = None
    try:
        read = settled_poses(s)
        if args.method != "paper":
            refuse_extrapolated_holds(read[0], s.folder)
    except (HoldsNeverSettle, NeverSettles) as exc:  # the holds do not settle, or there are none: the stream is the data
        if args.method == "paper":
            raise
        if motion_or_poses(args, exc, notes, s, other):  # calibrated from motion, its outputs written
            return 0
        if read is None:  # no poses were read to fall back on (never so: only a refusal after reading them allows it)
            raise
    poses, found = read
    say_reading(s, found, notes)
    spec, options = s.spec, platform_options(s)
    kind = getattr(args, "response_kind", "auto")
    for flag, value in (("--response", response), ("--response-kind", None if kind == "auto" else kind)):
        if value is not None:  # the holds settled: no response is fitted, said
            note = f"{flag} {value}: the holds settled, so no actuator response is fitted (not used)"
            warn(note)
            notes.append(note)
    progress = None if args.quiet else progress_printer(poses.length_unit)
    free = None
    if args.free is not None:
        free = [] if args.free.strip().lower() == "none" else [f.strip() for f in args.free.split(",") if f.strip()]
    if args.method == "paper":
        from platkit.calibrate.paper import calibrate_paper

        if args.max_evaluations is not None and args.max_evaluations < 1:
            raise BadInput(f"--max-evaluations {args.max_evaluations}: use a positive number")
        if poses.n_bodies:  # the paper's method knows markers only: bodies left out, and said
            warn(f"rigid bodies {', '.join(poses.body_names)} left out: --method paper reads the markers only")
            poses.body_names, poses.bodies, poses.n_body_samples = [], None, None
        cal = calibrate_paper(poses, spec, free=free, max_evaluations=args.max_evaluations, progress=progress,
                              platform_options=options)
    else:
        from platkit.calibrate.estimate import calibrate
        from platkit.calibrate.selection import select_model

        ridge_m = 0.0 if args.prior_strength is None else args.prior_strength * length_scale(poses.length_unit)
        if free is None and not args.no_selection:
            cal = select_model(poses, spec, robust=not args.no_robust, folds=args.folds, progress=progress,
                               platform_options=options, ridge_m=ridge_m)
        else:
            cal = calibrate(poses, spec, free=free, robust=not args.no_robust, folds=args.folds, progress=progress,
                            platform_options=options, ridge_m=ridge_m)
    if other is not None:
        from platkit.calibrate.estimate import second_session_errors

        cal.heldout["second_session"] = second_session_errors(cal, other)
    s = length_scale(cal.length_unit)
    # every warning is said before the outputs are written, so that the report lists it too
    second = cal.heldout.get("second_session")
    if second is not None and second["rms"] > SAME_FRAME_RATIO * max(cal.rms_after, 1e-12):
        warn(f"the second session's rms is {second['rms'] / max(cal.rms_after, 1e-12):.0f} times "
             f"the fit's: was {args.validate} recorded in the same motion-capture frame?")
    limit = cal.identifiability.get("at_plausible_limit") or []
    if limit:
        warn(f"{', '.join(limit)} reached the edge of the plausible range (nominal +- 100 typical "
             "corrections): the geometric model is absorbing something it does not describe; run platkit diagnose")
    fit_notes = list(cal.warnings)
    for w in fit_notes:
        warn(w)
    failure = fit_failure(cal)  # in the report as a warning; on stderr as the error line at the end
    cal.warnings = all_warnings(notes, fit_notes, [failure] if failure else [])
    said_before = len(cal.warnings)
    written = write_outputs(cal, args.out, poses, with_html=not args.no_report)
    for w in cal.warnings[said_before:]:  # what writing found (a calibrated.urdf not written, and why)
        warn(w)
    line = _rms_line(cal, s)
    from platkit.calibrate.estimate import rejected_by_body, rejected_by_marker

    lost = rejected_by_marker(cal)
    if lost:
        line += (f"; {sum(n for n, _ in lost.values())} marker observations rejected as outliers ("
                 + ", ".join(f"{k} {n}" for k, (n, _) in lost.items()) + ")")
    lost_bodies = rejected_by_body(cal)
    if lost_bodies:
        line += (f"; {sum(n for n, _, _ in lost_bodies.values())} rigid-body observations rejected as outliers ("
                 + ", ".join(f"{k} {n} of {seen}" for k, (n, _, seen) in lost_bodies.items()) + ")")
    if args.folds and "rms" in cal.heldout:
        line += f"; {args.folds}-fold held-out rms {cal.heldout['rms'] / s:.4g} {cal.length_unit}"
    if second is not None:
        line += f"; second session ({second['n_poses']} poses) rms {second['rms'] / s:.4g} {cal.length_unit}"
    chosen = cal.identifiability.get("model_selection") or {}
    if chosen.get("candidates"):
        held = chosen.get("held") or []
        line += (f"; free: {', '.join(chosen['chosen'])} (chosen by held-out prediction"
                 + (f"; held: {', '.join(held)})" if held else ")"))
    if failure:  # the outputs are whole, for inspection; the exit status says the fit failed
        print(f"{line}; wrote {', '.join(str(p) for p in written)}")
        raise ComputationFailed(f"{failure}; the outputs in {args.out} are written for inspection only")
    print(f"{line}; wrote {', '.join(str(p) for p in written)}")
    return 0


#: a fit whose rms ends above this many times its start's made it worse (any method)
WORSE_THAN_START = 1.001


def fit_failure(cal) -> str | None:
    """Why ``cal`` is not a calibration to use, or None: its method did not converge, or it ended
    with a larger rms than it started from. calibrate writes the outputs whole (for inspection),
    says this as a warning in the report, and exits 1 (ComputationFailed)."""
    s = length_scale(cal.length_unit)
    rms = f"rms {cal.rms_before / s:.4g} -> {cal.rms_after / s:.4g} {cal.length_unit}"
    steps = "evaluations" if cal.method == "paper" else "iterations"
    if not cal.converged:
        still = [w for w in cal.warnings if w.startswith("the fit stopped ")]  # the last iterations judged (calibrate.solve)
        return (f"not converged: --method {cal.method} stopped after {cal.iterations} {steps} without meeting its "
                f"tolerance ({rms})" + ("; raise --max-evaluations" if cal.method == "paper" else "")
                + ("; what still moves: the warning 'the fit stopped ...' above" if still else ""))
    if cal.rms_after > WORSE_THAN_START * cal.rms_before:
        return f"not converged to a better fit: --method {cal.method} ended worse than its start ({rms})"
    return None


def all_warnings(*groups: list[str]) -> list[str]:
    """Every warning said while the verb ran (platkit.notices) and those of ``groups`` (for a
    caller outside the CLI), each once, in order."""
    out: list[str] = []
    for w in [w for g in groups for w in g] + said():
        if w not in out:
            out.append(w)
    return out


#: the parts --response adds to the actuators' response (platkit.calibrate.motion.calibrate_motion's options)
RESPONSE_PARTS = {"delays": "delays", "rate-limit": "rate_limit"}


def response_parts(text: str | None) -> dict[str, bool]:
    """calibrate_motion's options of ``--response`` (BadInput naming an unknown part)."""
    parts = [] if text is None else [x.strip() for x in text.split(",") if x.strip()]
    unknown = [x for x in parts if x not in RESPONSE_PARTS]
    if unknown or (text is not None and not parts):
        raise BadInput(f"--response {text}: use {' and/or '.join(RESPONSE_PARTS)}, comma-separated")
    return {RESPONSE_PARTS[x]: True for x in parts}


def second_session(args, platform: str):
    """The poses of ``--validate``'s session (None without it), read as calibrate's own session is,
    for ``platform``."""
    if args.validate is None:
        return None
    return load_for_calibration(args.validate, platform, args.description, quiet=args.quiet)[0]


def motion_or_poses(args, refused, notes: list[str], s=None, other=None) -> bool:
    """Calibration from motion of a session whose holds were refused (``refused``: HoldsNeverSettle
    or NeverSettles; ``s``: the session as read, and ``other`` the ``--validate`` session's poses
    (:func:`second_session`), both read here where ``s`` is None): True when it ran (its
    outputs written). Where the refusal left the holds' poses usable (every hold settled or
    extrapolated to rest, ``settling['poses_usable']``: :func:`refuse_extrapolated_holds`) and the
    fitted motion model does not explain the stream (platkit.calibrate.motion.MotionUnexplained),
    the session is calibrated from those poses instead, said once on stderr and in the report's
    warnings with both reasons: False (the caller calibrates the poses it read). Any other
    failure of the motion fit is raised after a warning that says the stream was tried and why."""
    from platkit.calibrate.motion import MotionUnexplained
    from platkit.errors import PlatkitError

    reason = refused.settling.get("reason")
    try:
        run_motion(args, str(refused), notes, reason, s, other)
        return True
    except PlatkitError as exc:
        if not (isinstance(exc, MotionUnexplained) and refused.settling.get("poses_usable")):
            warn(f"{holds_refused(reason)}: the whole stream was tried through the actuators' fitted response instead")
            raise
        note = (f"{holds_refused(reason)}: the stream's motion model was tried and {exc}; calibrated from the holds' "
                "poses instead (settled and extrapolated to rest)")
    warn(note)
    notes.append(note)
    return False


def run_motion(args, why: str, notes: list[str], settle_reason: str | None = None, s=None, other=None) -> int:
    """``platkit calibrate`` on a session whose holds do not settle (or that has none): geometry,
    markers, frame and the actuators' response fitted to the whole stream (platkit.calibrate.motion),
    with the stand's default free parameters (``--free`` as given). What the reading kept with a
    warning (a control past its limit within the recording tolerance, an imported file's summary) is
    said and reported as on the settled path. ``why``: the settling search's refusal (the report's);
    ``settle_reason``: its clause with the counts (HoldsNeverSettle.settling['reason']), said in the
    one-line warning, once the fit has ended (before the outputs are written); ``s``: the session
    as read, and ``other`` the ``--validate`` session's poses (both read here where ``s`` is None)."""
    from platkit.calibrate.estimate import second_session_errors
    from platkit.calibrate.motion import calibrate_motion
    from platkit.calibrate.motion_points import bodies_alone, calibrate_motion_bodies
    from platkit.calibrate.report import write_outputs

    if s is None:
        s = read_session(args.session, args.platform, args.description, quiet=True)
        other = second_session(args, s.spec.name)
    for kept in s.extras.get("control_notes", []):  # the reading's warnings, as the settled path says them
        if kept not in notes:
            warn(kept)
            notes.append(kept)
    options = {"moving_link": s.moving_link} if s.moving_link else {}
    free = None
    if args.free is not None:
        free = [] if args.free.strip().lower() == "none" else [f.strip() for f in args.free.split(",") if f.strip()]
    reason = f"settling: {why}"
    ridge_m = 0.0 if args.prior_strength is None else args.prior_strength * length_scale(s.length_unit)
    fit = calibrate_motion_bodies if bodies_alone(s) else calibrate_motion  # bodies alone: as points
    cal, poses = fit(s, s.spec, free=free, robust=not args.no_robust,
                     progress=None if args.quiet else motion_progress_printer(
                         s.length_unit, getattr(args, "response_kind", "auto").replace("-", "_")),
                     platform_options=options, ridge_m=ridge_m, reason=reason,
                     kind=getattr(args, "response_kind", "auto").replace("-", "_"),
                     **response_parts(getattr(args, "response", None)))
    if other is not None:
        cal.heldout["second_session"] = second_session_errors(cal, other)
    note = fallback_note(settle_reason)  # said once the stream has calibrated: it is the outcome
    warn(note)
    fit_notes = list(cal.warnings)
    for w in fit_notes:
        warn(w)
    cal.warnings = all_warnings(notes, [note], fit_notes)  # said before writing: the report lists them
    said_before = len(cal.warnings)
    written = write_outputs(cal, args.out, poses, with_html=not args.no_report)
    for w in cal.warnings[said_before:]:  # what writing found (a calibrated.urdf not written, and why)
        warn(w)
    sc = length_scale(cal.length_unit)
    r = cal.motion["response"]
    # the slowest of the actuators whose response the markers saw (a tree's joint that moves no
    # marker keeps the start, held)
    taus = {c: e["tau_s"]["value"] for c, e in r["actuators"].items() if e["tau_s"]["status"] == "estimated"} or {
        c: e["tau_s"]["value"] for c, e in r["actuators"].items()}
    slow = max(taus, key=lambda c: taus[c])
    line = (f"rms {cal.rms_before / sc:.4g} -> {cal.rms_after / sc:.4g} {cal.length_unit} from motion "
            f"({cal.motion['samples']['n_used']} of {cal.motion['samples']['n_stream']} samples as "
            f"{cal.motion['samples']['n_fitted']} poses, {_observed(cal)}); response {r['kind']} after a "
            f"{r['reference']} reference ({_kind_said(r)}): shift {r['shift_s']['value']:.4g} s, "
            f"slowest {slow} tau {taus[slow]:.4g} s")
    if r.get("not_determined"):
        line += f"; not determined: {', '.join(r['not_determined'])}"
    left = cal.motion["samples"].get("n_in_start_transient")
    if left:  # the first command's transient, left out of the fit (platkit.calibrate.motion_transient)
        line += f"; {left} samples of the first command's transient left out"
    past = cal.motion["samples"].get("n_past_the_log")
    if past:  # past the end of a log cut in motion, left out of the fit (platkit.calibrate.stream.past_log_end)
        line += f"; {past} samples past the end of the command log left out"
    bodies = cal.motion["samples"].get("rigid_bodies")
    if bodies:  # the body samples of the windows kept as samples serve (platkit.calibrate.motion_bodies)
        line += f"; rigid bodies {', '.join(bodies['bodies'])} from {bodies['n_used']} of {bodies['n_samples']} samples"
    second = cal.heldout.get("second_session")
    if second is not None:
        line += f"; second session ({second['n_poses']} poses) rms {second['rms'] / sc:.4g} {cal.length_unit}"
    print(f"{line}; wrote {', '.join(str(p) for p in written)}")
    return 0


def fallback_note(reason: str | None) -> str:
    """The one-line warning of a calibration from motion in place of one from settled holds, with
    why (``reason``: the settling search's, HoldsNeverSettle.settling['reason'], with its counts)."""
    return f"{holds_refused(reason)}: calibrated from the whole stream through the actuators' fitted response instead " \
           "(report: motion)"


def holds_refused(reason: str | None) -> str:
    """Why the holds were not calibrated from, in a few words (``reason`` as :func:`fallback_note`'s)."""
    return f"too few holds settle: {reason}" if reason else "the holds do not settle or there are none"


def _rms_line(cal, s: float) -> str:
    """The summary line's start: the rms before and after, and what it was measured on (poses,
    markers, rigid bodies, each counted in the number's grammar)."""
    n_bodies = len(cal.body_names)
    return (f"rms {cal.rms_before / s:.4g} -> {cal.rms_after / s:.4g} {cal.length_unit} "
            f"({cal.n_poses} pose{'s' if cal.n_poses != 1 else ''}, "
            f"{cal.n_markers} marker{'s' if cal.n_markers != 1 else ''}"
            + (f", {n_bodies} rigid bod{'ies' if n_bodies != 1 else 'y'} (rho {cal.body_rho_source})"
               if n_bodies else "") + ")")


def _observed(cal) -> str:
    """What the fit observed, in a few words: its markers, or the rigid bodies read as points
    (platkit.calibrate.motion_points)."""
    points = cal.motion.get("bodies_as_points")
    if points:
        return (f"no markers: rigid bodies {', '.join(points['bodies'])} read as {len(points['points'])} points, "
                f"placements read back")
    return f"{cal.n_markers} marker{'s' if cal.n_markers != 1 else ''}"


def _kind_said(r: dict) -> str:
    """How the response's kind was chosen, in a few words (report: motion.response.choice)."""
    choice = r.get("choice") or {}
    if choice.get("asked") != "auto":
        return "named"
    bic = choice.get("bic") or {}
    if r["kind"] == "first_order":
        tried = [k for k in bic if k != "first_order"]
        return ("chosen: second order not better (whole BIC, fast content)" if tried
                else "chosen: no actuator's second order determined")
    seen = [e for e in r["actuators"].values() if e["tau_s"]["status"] == "estimated"]
    n2 = sum(1 for e in seen if e.get("kind") == "second_order")
    return f"chosen: second order for {n2} of the {len(seen)} actuators seen, lower BIC, fast content kept"


#: a second session this many times worse than the fit is most likely in another mocap frame
SAME_FRAME_RATIO = 20.0
