"""platkit diagnose: find the physics a calibration left out, model it, prove it held out."""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

from platkit.errors import BadInput
from platkit.notices import warn


def add_parser(sub):
    p = sub.add_parser("diagnose", help="locate structured residuals, name and model the missing effect "
                                        "(diagnosis.json, calibration.yaml, report.html)")
    p.add_argument("session", help="session folder (the one the calibration was fitted on, or another)")
    p.add_argument("--calibration", required=True, help="calibration.yaml to diagnose (from `platkit calibrate`)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--heldout", default=None, help="another session of the same stand and mocap frame, scored "
                                                   "before and after (never used to choose); a stream without "
                                                   "holds is scored on its windows, each model reading them "
                                                   "through its own actuator response")
    p.add_argument("--heldout-register", type=int, default=None, metavar="K",
                   help="the --heldout session was recorded in a motion-capture set-up of its own (another day: the "
                        "cameras calibrated again, the robot moved): score it also with each model re-registered to "
                        "that set-up, K consecutive poses fitting the base-to-mocap transform (every other parameter "
                        "held) and the other poses scored, the blocks rotating so that every pose is scored "
                        "(diagnosis.json heldout_session.registered)")
    p.add_argument("--register-markers", action="store_true",
                   help="with --heldout-register: re-fit the marker places on their links too (a marker body mounted "
                        "again)")
    p.add_argument("--register-spread", action="store_true",
                   help="with --heldout-register: each block's K poses taken across the recording (every B-th pose), "
                        "as a registration set that spans the workspace, instead of K consecutive ones")
    p.add_argument("--folds", type=int, default=5, help="K of the K-fold held-out test (default 5)")
    p.add_argument("--alpha", type=float, default=0.01, help="family-wise level of the tests (default 0.01)")
    p.add_argument("--max-effects", type=int, default=None, metavar="N",
                   help="most effects to name (default: 3 on a stand or a chain, 3 for each tracked link of a tree); "
                        "a search the cap ends, not a test, says 'stopped at the cap of N effects'")
    p.add_argument("--keep-geometry", action="store_true",
                   help="keep the calibration's free parameters (default: a parameter group it held is freed again "
                        "before a term mostly inside the geometry would be named, when that predicts held-out poses "
                        "better)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--no-report", action="store_true",
                   help="write diagnosis.json and calibration.yaml only, not report.html (its figures take "
                        "longer than a small diagnosis)")
    return p


def with_body_points(poses, folder, session=None):
    """A session's rigid bodies as diagnosis reads them: each body as three points rigidly
    attached to it (platkit.diagnose.bodies.as_points: ``<body>.o``, ``<body>.x``, ``<body>.y``, its
    origin and axis tips), beside the markers, their noise measured on the recording's body
    stream (``session``, the session as read) where it has one; said in one line."""
    if not poses.n_bodies:
        return poses
    from platkit.bodies import frame_point_names
    from platkit.diagnose.bodies import LEVER_M, as_points

    stream = None if session is None or session.bodies is None or session.poses is not None else session.bodies
    said = ", ".join(f"{b} as {'/'.join(frame_point_names(b))}" for b in poses.body_names)
    warn(f"{folder}: rigid bodies diagnosed as three points each, origin and axis tips at "
         f"{LEVER_M * 1e3:g} mm ({said})")
    return as_points(poses, stream, str(folder))


def run(args) -> int:
    from platkit.commands.common import read_with_calibration
    from platkit.diagnose import Options, diagnose
    from platkit.diagnose.bodies import body_calibration, on_bodies, point_calibration
    from platkit.diagnose.report import write_outputs
    from platkit.io.atomic import check_output_dir
    from platkit.io.calibration import read_calibration
    from platkit.model import length_scale

    check_output_dir(args.out)
    if args.folds < 2:
        raise BadInput(f"--folds {args.folds}: use 2 or more")
    if not 0 < args.alpha < 1:
        raise BadInput(f"--alpha {args.alpha}: must lie between 0 and 1")
    if args.max_effects is not None and args.max_effects < 1:
        raise BadInput(f"--max-effects {args.max_effects}: must be 1 or more")
    if not Path(args.calibration).is_file():
        raise BadInput(f"{args.calibration}: calibration file not found")
    cal = read_calibration(args.calibration)
    as_read = cal  # written again as it is where the diagnosis changes nothing in the model

    sessions = {}  # folder -> the session as read: its streams are read once

    from platkit.commands.calibrate import refuse_extrapolated_holds, settling_notes
    from platkit.diagnose.stream import heldout_stream, read_through, stream_why, training_stream
    from platkit.settle import HoldsNeverSettle, NeverSettles

    def settled(folder, stream_if_extrapolated=False):
        """The session's settled poses, its bodies as points, what settling dropped said; raises
        HoldsNeverSettle / NeverSettles where its holds do not settle (fewer than half the commands),
        and with ``stream_if_extrapolated`` where holds were extrapolated to rest (calibrate.refuse_extrapolated_holds)."""
        poses = read_with_calibration(folder, cal, args.calibration, args.quiet, read=sessions)[1]
        notes = settling_notes(poses, folder)  # dropped commands by reason, holds extrapolated to rest
        if stream_if_extrapolated:
            refuse_extrapolated_holds(poses, folder)
        poses = with_body_points(poses, folder, sessions.get(folder))  # said once settled, not before
        for note in notes:
            warn(note)
        return poses

    streamed = False  # the session read as a stream through its calibrated response
    refused: dict = {}  # the settle search's refusal of the session's holds (HoldsNeverSettle.settling)
    try:
        # a calibration from motion (calibrate's rule for holds extrapolated to rest) reads the stream then too
        poses = settled(args.session, stream_if_extrapolated=bool(cal.motion))
    except (HoldsNeverSettle, NeverSettles) as exc:  # holds extrapolated or unsettled: a calibration from motion reads the stream
        if not cal.motion:
            raise type(exc)(f"{exc}; a stream without settled holds is diagnosed with its calibration from motion "
                            "(platkit calibrate on it)") from exc
        refused = dict(exc.settling)
        poses, cal = training_stream(args.session, sessions[args.session], cal, stream_why(refused))
        streamed = True
    if poses.n_poses < 2 * args.folds:
        raise BadInput(f"{args.session}: {poses.n_poses} poses are too few for {args.folds}-fold held-out tests")
    heldout, held_stream = None, None
    if args.heldout:
        try:
            heldout = settled(args.heldout)
        except (HoldsNeverSettle, NeverSettles) as exc:  # a held-out stream: read through the response
            if not as_read.motion:
                raise type(exc)(f"{exc}; a held-out stream without settled holds is read through the actuator "
                                f"response of a calibration from motion, and {args.calibration} has none") from exc
            held_stream = heldout_stream(args.heldout, sessions[args.heldout], as_read, stream_why(exc.settling))
            heldout = read_through(held_stream, as_read, as_read.spec)  # at the given response, without nodes
    given, cal = cal, point_calibration(cal)  # the bodies' points placed where the bodies' placements put them
    if args.heldout_register is not None or args.register_markers or args.register_spread:
        _check_register(args, cal, heldout)
    say = None if args.quiet else (lambda line: print(f"diagnose: {line}", file=sys.stderr, flush=True))
    d = diagnose(cal.spec, poses, Options(alpha=args.alpha, folds=args.folds, max_effects=args.max_effects,
                                         reopen_geometry=not args.keep_geometry),
                 heldout=None if held_stream is not None else heldout, progress=say, start=cal)
    unchanged = d.calibration is cal  # nothing named and no geometry chosen again: the start itself
    held_after = heldout  # the held-out poses as the diagnosed model reads them
    if held_stream is not None:  # each model reads the held-out stream through its own response
        from platkit.diagnose.stream import score_heldout_stream
        from platkit.diagnose.verdict import verdict

        d.heldout_session = score_heldout_stream(d.base, d.calibration, held_stream, cal.spec, d.findings)
        d.verdict = verdict(d)
        heldout, held_after = read_through(held_stream, d.base, cal.spec), read_through(held_stream, d.calibration,
                                                                                        cal.spec)
    if streamed:
        from platkit.calibrate.motion import without_response  # the response back into actuator_response
        from platkit.diagnose.response_kind import ROUND_RESPONSE

        d.calibration = without_response(d.calibration, sessions[args.session])
        again = next((r for r in reversed(d.rounds) if r.get("round") == ROUND_RESPONSE and r.get("kept")), None)
        if again is not None:  # the response's kind chosen again by diagnosis: said in calibration.yaml
            motion = d.calibration.motion
            motion["why"] = (f"{motion.get('why', '')}; the response chosen again by platkit diagnose: "
                             f"{again['tried']} (diagnosis.json, rounds)")
        named_from_settle_summary(d, refused, as_read, say)
    if args.heldout_register is not None and d.heldout_session is not None:
        from platkit.diagnose.registered import registered_heldout

        d.heldout_session["registered"] = registered_heldout(d.base, d.calibration, heldout, args.heldout_register,
                                                             args.register_markers, spread=args.register_spread,
                                                             heldout_after=held_after)
    if (Path(args.session) / "imu.csv").is_file():
        # the parameters held at nominal are the given calibration's (the diagnosis refits with them fixed)
        d.imu, d.calibration.imu = _diagnose_imu(args.session, d.calibration, say, cal.td_status,
                                                 read=sessions[args.session])
    # the file's calibration as read where nothing changed the model (a stream's response, a body's
    # placement and their std as calibrate wrote them); else the bodies again, placed from their points
    d.calibration = replace(as_read, imu=d.calibration.imu) if unchanged else body_calibration(d.calibration, given)
    on_bodies(d.findings, given.body_names)  # a finding at a body's point names the body too
    written = write_outputs(d, args.out, with_html=not args.no_report)
    s = length_scale(d.unit)
    names = ", ".join([f.effect for f in d.findings] + [f["effect"] for f in (d.imu or {}).get("findings", [])]) or "no finding"
    print(f"{names}; geometric rms {d.base.rms_after / s:.4g} -> {d.final_fit.rms_after / s:.4g} {d.unit}; "
          f"wrote {', '.join(str(p) for p in written)}")
    if d.heldout_session is not None and "registered" in d.heldout_session:
        h, r = d.heldout_session, d.heldout_session["registered"]
        print(f"held-out session rms {h['rms_before'] / s:.4g} -> {h['rms_after'] / s:.4g} {d.unit} as is; "
              f"re-registered on {r['k']} {'spread ' if r['spread'] else ''}poses at a time: "
              f"{r['rms_before'] / s:.4g} -> {r['rms_after'] / s:.4g} {d.unit} (paired p = {r['p_improvement']:.2g})")
    return 0


#: the round of diagnosis.json that says what the settle summary of a motion-calibrated session named
ROUND_SETTLE_SUMMARY = "settle summary"


def named_from_settle_summary(d, refused: dict, cal, say=None) -> None:
    """On a session calibrated from motion because its holds never settled (``refused``: the
    settle search's HoldsNeverSettle.settling; ``cal`` the calibration given): the slow actuator
    its summary names, as the first finding (platkit.diagnose.recording.lag_from_settle_summary's
    rule), the round that says where it came from (diagnosis.json ``rounds``), and the verdict
    said again; where the search named that effect itself (a term on the stream), its finding says
    the summary's reading instead of a second one. A lack of fit the stream's search reported
    (``unexplained``) stays beside it: the lag changes nothing in the model, so that misfit is
    still there, and the finding says the two are not told apart here and what could read so."""
    from platkit.diagnose.recording import FROM_SETTLE_SUMMARY, lag_from_settle_summary, unsettled_effect
    from platkit.diagnose.verdict import verdict
    from platkit.plugins import effect_library
    from platkit.settle import SettleOptions

    effect = unsettled_effect(effect_library())
    if not refused or effect is None:
        return
    held = d.heldout_geometric if d.heldout_geometric is not None else d.base.rms_after
    f = lag_from_settle_summary(refused, (cal.motion or {}).get("response"), held, effect.name,
                                SettleOptions().max_unsettled_fraction)
    name = None if f is None else f.effect
    same = None if name is None else next((x for x in d.findings if x.effect == name), None)
    if f is not None and same is not None:  # the search named it from the stream itself: one name, both readings
        same.evidence += (f"; the {FROM_SETTLE_SUMMARY} names it too, on actuator {f.where['actuator']} "
                          f"({f.where['holds']} of {f.where['of_commands']} holds never settled, time constant "
                          f"{f.parameters['time_constant']['value']:.3g} s)")
    d.rounds.append({"round": ROUND_SETTLE_SUMMARY, "from": FROM_SETTLE_SUMMARY, "reason": refused.get("reason"),
                     "named": [] if f is None or same is not None else [f.effect],
                     **({"already_named": name} if same is not None else {}),
                     "rule": "named where the session has holds (more than one settled), more than the settle search's "
                             "max_unsettled_fraction never settled, and the search named the actuators still moving "
                             "and fitted their time constant"})
    if f is None or same is not None:
        d.verdict = verdict(d)
        return
    for x in (x for x in d.findings if x.effect == "unexplained"):
        marker = x.where.get("marker")
        at = (f" at marker {marker}, {'one' if marker in f.where['markers'] else 'none'} of the markers the slow "
              f"actuator still moved ({', '.join(f.where['markers'])})" if marker else "")
        f.warnings.append(f"the stream's lack of fit (unexplained{at}) stays beside it: naming the lag changes nothing "
                          "in the model, so the two are not told apart on this session (a response that does not "
                          "follow this lag, or marker noise correlated over the windows beyond what the noise floor "
                          "counts, would read so)")
    d.findings.insert(0, f)
    if say:
        say(f"{f.effect}: {f.evidence}")
    d.verdict = verdict(d)


def _check_register(args, cal, heldout) -> None:
    """--heldout-register K: bad input in one line without --heldout, with K that leaves no pose
    to score, or a block of K poses that cannot fix the set-up (checked on the given calibration
    before the diagnosis runs, without fitting: the re-registrations run once, after it)."""
    from platkit.calibrate.reregister import check_registration

    if args.heldout_register is None:
        raise BadInput(f"--register-{'markers' if args.register_markers else 'spread'}: give --heldout-register K "
                       "(the poses each re-registration fits)")
    if heldout is None:
        raise BadInput(f"--heldout-register {args.heldout_register}: give --heldout SESSION (the session to "
                       "re-register and score)")
    check_registration(cal, heldout, args.heldout_register, args.register_markers, spread=args.register_spread)


def _diagnose_imu(session, cal, say, td_status=None, read=None) -> tuple[dict, dict]:
    """The IMU diagnosis of a session with imu.csv and commands (platkit.diagnose.imu): the
    mapping diagnosis.json holds (a session the IMU cannot be diagnosed on says why) and what
    its accepted findings add to calibration.yaml (its ``imu`` mapping; empty without). ``read``:
    the session already read (load_session), so that its streams are not read again."""
    from platkit.diagnose.imu import diagnose_imu, td_covariance
    from platkit.errors import ComputationFailed
    from platkit.io.session import load_session

    s = load_session(session, platform=cal.platform) if read is None else read
    if s.commands is None or s.imu_stream is None:
        return {"findings": [], "verdict": "IMU not diagnosed: the session has no commands with its imu.csv."}, {}
    try:
        r = diagnose_imu(cal.spec, cal.td, s.command_t, s.commands, s.imu_stream, td_cov=td_covariance(cal),
                         td_status=cal.td_status if td_status is None else td_status)
    except ComputationFailed as exc:
        return {"findings": [], "verdict": f"IMU not diagnosed: {exc}"}, {}
    if say:
        say(r.verdict)
    return r.to_dict(), r.calibration_entry()
