"""What diagnosis says when no effect of the library is named: a lack of fit, or a weak one.

With nothing found, a geometric model that still predicts held-out poses at more than
``lack_of_fit_factor`` times the noise floor is a lack of fit the library has no name for
(``unexplained``). Within that factor, held-out prediction cannot tell a weak lack of fit from
noise; the neighbour tests (locate.neighbour_tests) can, where it is smooth in time or over the
commands: residuals alike at poses next in time or with near commands are ``unexplained`` too; not
on a stream's windowed poses, whose neighbouring nodes share the markers' coloured noise
(platkit.diagnose.stream.nodes_share_noise).
"""
from __future__ import annotations

from collections.abc import Callable

from platkit.diagnose.fitting import ROUND_NEIGHBOURS, Finding, Fit, Options, _fmt_rms, body_residuals, extrapolated
from platkit.diagnose.floor import pose_words, worst_marker
from platkit.diagnose.locate import along_main_direction, neighbour_tests
from platkit.diagnose.stream import nodes_share_noise
from platkit.poses import PoseSet


def _response_clause(poses: PoseSet) -> str:
    """On a stream's windowed poses, what else the excess over the floor can be: the controls at
    the nodes are the calibrated response's, not measured, so its own misfit is in the residuals."""
    if "node" not in poses.extras:
        return ""
    return ("; on a stream the controls at the windows' nodes are the calibrated actuator response's, so its own "
            "misfit shows here too: a response of another kind may take it (platkit calibrate --response-kind, "
            "--response)")


def lack_of_fit(cur: Fit, poses: PoseSet, floor: float, held: float, opt: Options,
                say: Callable[[str], None]) -> tuple[Finding | None, dict | None]:
    """(the ``unexplained`` finding or None, the round of neighbour tests or None) for a search
    that named nothing: ``cur`` the geometric model, ``held`` its held-out RMS on the settled
    (or a stream's windowed) poses, ``floor`` the noise floor of held-out prediction."""
    unit = poses.length_unit
    ratio = held / floor
    if held > opt.lack_of_fit_factor * floor:
        worst = worst_marker(cur.r, poses)
        say(f"lack of fit: held-out {_fmt_rms(held, unit)} is {ratio:.1f} times the noise floor, nothing in "
            "the library explains it: unexplained")
        return Finding(
            effect="unexplained", where={"fit": "every pose", **({"marker": worst} if worst else {})}, parameters={},
            heldout_rms_before=cur.cv_rms, heldout_rms_after=cur.cv_rms,
            evidence=(f"the geometric model predicts held-out poses at {_fmt_rms(held, unit)}, {ratio:.1f} times "
                      f"the noise floor of these {pose_words(poses)} ({_fmt_rms(floor, unit)}), and no effect in the library "
                      "predicts them better: the stand does something the library does not hold"
                      + (f" (the largest residuals on marker {worst})" if worst else "") + _response_clause(poses))), None
    if not held <= opt.lack_of_fit_factor * floor or extrapolated(poses).any():
        return None, None
    if nodes_share_noise(poses):  # neighbouring nodes share coloured noise: alike in time whatever the model
        say(f"held-out {_fmt_rms(held, unit)} is {ratio:.1f} times the noise floor, within "
            f"{opt.lack_of_fit_factor:g}: the neighbour tests are not run on windowed poses (neighbouring nodes share "
            "the markers' coloured noise)")
        return None, None
    # Not in a session whose holds were extrapolated to rest: the approach's remnant reaches the
    # settled poses too. In the room's frame (a drift of the
    # cameras) and in the moving frame (a sway of the marker mount: one direction of the moving
    # part, which turns with the stand in the room)
    frames = {"motion capture": cur.r, "moving": body_residuals(cur, poses)}
    near = neighbour_tests(frames, poses)
    if not near:
        return None, None
    tests = {"round": ROUND_NEIGHBOURS, "tests": [
        {"test": x.test, "frame": x.where["frame"], "statistic": float(x.statistic), "p": float(x.p),
         "p_adjusted": float(x.p_adjusted)} for x in near]}
    top = near[0]
    if not top.p_adjusted < opt.alpha:
        return None, tests
    x_pose, x_neighbour = along_main_direction(frames[top.where["frame"]], top.detail["a"], top.detail["b"])
    worst = worst_marker(cur.r, poses)
    say(f"residuals alike at {top.where['alike']} (adjusted p = {top.p_adjusted:.2g}), held-out "
        f"{ratio:.1f} times the noise floor, nothing in the library explains it: unexplained")
    return Finding(
        effect="unexplained", where={"fit": "every pose", **top.where, **({"marker": worst} if worst else {})},
        parameters={}, heldout_rms_before=cur.cv_rms, heldout_rms_after=cur.cv_rms,
        regressor=x_pose, signature_before=x_neighbour,
        regressor_label=f"error at a {pose_words(poses)[:-1]}, along the residuals' main direction",
        evidence=(f"the geometric model's residuals are alike at {top.where['alike']} in the "
                  f"{top.where['frame']} frame (correlation {top.statistic:.2f}, permutation p = {top.p:.2g}, "
                  f"{top.p_adjusted:.2g} adjusted for {len(near)} tests), though it predicts held-out poses at "
                  f"{_fmt_rms(held, unit)}, only {ratio:.1f} times the noise floor; no effect in the library predicts "
                  "them better: a weak effect of a shape the library does not hold" + _response_clause(poses)),
        p_screen=float(top.p_adjusted)), tests
