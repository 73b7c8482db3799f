"""The diagnosis said in one paragraph for people (platkit.diagnose.search)."""
from __future__ import annotations

from platkit.diagnose.fitting import (
    FROM_NO_MARKER,
    FROM_SETTLED_STREAM,
    FROM_SLOW_APPROACH,
    ROUND_BESIDE_PROBE,
    ROUND_BESIDE_TIME,
    ROUND_BY_REMOVAL,
    ROUND_NEIGHBOURS,
    ROUND_WEAK_NAMES,
    Diagnosis,
    _fmt_rms,
    _where_text,
)
from platkit.diagnose.floor import pose_words
from platkit.diagnose.locate import located


def verdict(d: Diagnosis) -> str:
    """One paragraph for people."""
    unit = d.unit
    named = [f for f in d.findings if f.effect != "unexplained"]
    unexpl = [f for f in d.findings if f.effect == "unexplained"]
    parts = []
    parts += _nothing_found(d)
    if named:
        first_before = max(f.heldout_rms_before for f in named)
        last_after = min(f.heldout_rms_after for f in named)
        names = ", ".join(f"{f.effect} ({_where_text(f.where)})" for f in named)
        if last_after < first_before:
            parts.append(f"The geometric model leaves out {names}. Modelling {'it' if len(named) == 1 else 'them'} "
                         f"brings the held-out RMS from {_fmt_rms(first_before, unit)} to {_fmt_rms(last_after, unit)}.")
        else:  # a slow actuator read from the stream, its holds already extrapolated by the settling search
            parts.append(f"The recording shows {names}; the held-out RMS stays {_fmt_rms(last_after, unit)}.")
    capped = next((r for r in d.rounds if r.get("at_cap")), None)
    if capped is not None:
        parts.append(f"The search {capped['at_cap']}; more may be left to name (--max-effects sets the cap).")
    for r in d.rounds:
        note = r.get("geometry_reopened")
        if note:
            parts.append(f"Before a term mostly inside the geometry was named, the geometry the calibration held "
                         f"({', '.join(note['groups'])}) was freed again: it predicts held-out poses "
                         f"better ({_fmt_rms(note['heldout_rms_before'], unit)} -> "
                         f"{_fmt_rms(note['heldout_rms_after'], unit)}); calibration.yaml estimates it (--keep-geometry: not).")
    for r in d.rounds:
        note = r.get("geometry_reselected")
        if note:
            parts.append(f"After {note['after']} was accepted, the geometry's model "
                         f"selection was made again beside it: it frees {', '.join(note['chosen']) or 'no group'} and "
                         f"holds {', '.join(note['held']) or 'none'} (held-out {_fmt_rms(note['heldout_rms_before'], unit)} "
                         f"-> {_fmt_rms(note['heldout_rms_after'], unit)}); calibration.yaml estimates that set.")
        note = r.get("geometry_kept")
        if note:
            parts.append(f"After {note['after']} was accepted, the geometry's model selection made again would free "
                         f"{', '.join(note['chosen']) or 'no group'} and hold {', '.join(note['held']) or 'none'}, but it "
                         f"predicts {', '.join(w['link'] for w in note['links_worse'])} worse held out: the free "
                         "set in force is kept.")
    own = [f for f in named if f.corrected.startswith("by ")]  # corrected elsewhere than in the data: its own words
    for f in own:
        parts.append(f"{f.effect} describes the recording, not the stand: corrected {f.corrected}.")
    corrected = [f for f in named if f.corrected and f not in own]
    if corrected:
        parts.append(f"{' and '.join(sorted({f.effect for f in corrected}))} describe{'s' if len(corrected) == 1 else ''} "
                     "the recording, not the stand: corrected in the data, and calibration.yaml predicts where the "
                     "stand settles.")
    un = (d.poses.settling or {}).get("unsettled") or {}
    if un and not any(f.term is None for f in named):  # the stream's own finding says it
        parts.append(f"Settling: {un['sentence']}.")
    if d.too_few_settled:
        parts.append("Most holds never settled: the stand's physics was not tested, for lack of settled poses to "
                     "prove it on (extrapolated poses carry what their approach model missed, along the last move); "
                     "record longer holds to test it.")
    left = located(d.locations, 0.001) if named and not unexpl and not d.too_few_settled else []
    if left and any(f.term is not None for f in named):
        parts.append(f"Some structure remains in the residuals ({left[0].test}, {_where_text(left[0].where)}) that "
                     "held-out prediction does not see (within twice the noise floor): what the model leaves of the "
                     "physics it names, not reported as another effect.")
    parts += _taken_back(d)
    for f in unexpl:
        if "alike" in f.where:  # the neighbour tests (locate.neighbour_tests) near the noise floor
            parts.append(f"Structure remains that no known effect explains: {f.evidence}. It is reported as "
                         "unexplained rather than given a wrong name; more poses would show its shape.")
            continue
        parts.append(f"Structure remains that no known effect explains ({_where_text(f.where) or f.where}); "
                     "it is reported as unexplained rather than given a wrong name.")
    closest = [r["not_accepted"] for r in d.rounds if r.get("not_accepted")]
    if closest and not named and not d.too_few_settled:
        parts.append(f"The closest candidate in the library: {closest[-1]}.")
    for f in named:
        for w in f.warnings:
            parts.append(f"Warning on {f.effect}: {w}.")
        if f.alternatives:
            alts = ", ".join(f"{a['effect']} ({_where_text(a['where'])}, {_fmt_rms(a['heldout_rms'], unit)})"
                             for a in f.alternatives)
            parts.append(f"Not told apart on this plan: {f.effect} ({_where_text(f.where)}, held-out "
                         f"{_fmt_rms(f.heldout_rms_after, unit)}) and {alts} predict held-out poses as well as each "
                         "other: the effect is one of them, and this plan cannot tell which.")
    parts += _not_separable(d)
    if d.heldout_session is not None:
        h = d.heldout_session
        parts.append(f"On the separate held-out recording ({h['n_poses']} "
                     + ("windowed poses, each model reading its stream through its own actuator response"
                        if h.get("windowed") else "poses") + ") the point RMS goes from "
                     f"{_fmt_rms(h['rms_before'], unit)} to {_fmt_rms(h['rms_after'], unit)}.")
    return " ".join(parts)


def _nothing_found(d: Diagnosis) -> list[str]:
    """The sentences of a diagnosis that names nothing: at the noise floor, or near it."""
    unit = d.unit
    parts: list[str] = []
    if not d.findings and d.at_noise_floor:
        parts.append(f"The motion capture shows no hidden effect: the geometric model predicts held-out poses at "
                     f"{_fmt_rms(d.heldout_geometric, unit)}, the noise floor of these {pose_words(d.poses)} "
                     f"({_fmt_rms(d.noise_floor, unit)} from the marker noise and the samples averaged), so no "
                     "effect can predict them better; an effect the geometry absorbs on this plan would not show.")
    elif not d.findings and not d.too_few_settled:
        loc = located(d.locations, 0.01)
        ratio = (d.heldout_geometric / d.noise_floor if d.noise_floor and d.heldout_geometric is not None
                 else None)
        near = ratio is not None and ratio >= d.options.noted_lack_of_fit
        parts.append(("No hidden effect is claimed" if near else "The motion capture shows no hidden effect")
                     + ": no candidate effect passed the held-out test, and the residuals show no structure that "
                     "survives correction for multiple testing"
                     + ("" if not loc else f" (weakest remaining: {loc[0].test})") + ".")
        if near:
            tests = [t for r in d.rounds if r.get("round") == ROUND_NEIGHBOURS for t in r["tests"]]
            alike = ("; nor are its residuals more alike at poses next in time or with near commands than chance "
                     f"(adjusted p = {min(t['p_adjusted'] for t in tests):.2g}), as a drift, a sway or a bend would "
                     "leave them" if tests else "")
            parts.append(f"Yet the geometric model predicts held-out poses at {_fmt_rms(d.heldout_geometric, unit)}, "
                         f"{ratio:.2g} times the noise floor of these {pose_words(d.poses)} ({_fmt_rms(d.noise_floor, unit)}): "
                         "sessions with no hidden effect reach up to about twice the floor, and a weak effect of a "
                         f"shape the library does not hold sits there too{alike}. So the two cannot be told apart on "
                         "this session; more poses, or " + ("a longer stream" if "node" in d.poses.extras else "longer holds")
                         + ", would.")
    return parts


def _taken_back(d: Diagnosis) -> list[str]:
    """The sentences of the names taken back after the search (their rounds)."""
    parts: list[str] = []
    for r in d.rounds:
        if r.get("not_named") and r.get("round") == ROUND_BESIDE_PROBE:
            parts.append(f"{', '.join(r['not_named'])} predicted held-out poses better at first, but not beside the "
                         "generic model that still beats the named ones: a slice of the structure reported as "
                         "unexplained, not named.")
        elif r.get("not_named") and r.get("round") == ROUND_BESIDE_TIME:
            parts.append(f"{', '.join(r['not_named'])} predicted held-out poses better at first, but not beside a "
                         f"model of the structure in time that the residuals still hold ({r['located']}; a time "
                         f"probe of {r['time_bins']} bins): a slice of that structure, reported as unexplained, "
                         "not named.")
        elif r.get("not_named") and r.get("round") == ROUND_BY_REMOVAL:
            parts.append(f"{', '.join(r['not_named'])} predicted held-out poses better when named, but the model "
                         "without it predicts them as well beside the other effects named (paired p = "
                         f"{', '.join(f'{p:.2g}' for p in r['paired_p'].values())}): what it took is theirs, "
                         "so its name is taken back.")
        elif r.get("not_named") and r.get("round") == ROUND_WEAK_NAMES:
            parts.append(f"{', '.join(r['not_named'])} passed the held-out test only weakly, and the model with "
                         f"{'it' if len(r['not_named']) == 1 else 'them'} still left held-out poses at more than "
                         "twice the noise floor with structure located: a slice of physics the library does not "
                         "hold, not named.")
    return parts


def _not_separable(d: Diagnosis) -> list[str]:
    """The sentences of the terms set aside (by the recording, or not separable from the
    geometry) and of the effects that could not be tried."""
    parts: list[str] = []
    echo = [x for x in d.not_separable if str(x.get("from", "")).startswith(FROM_SLOW_APPROACH)]
    stream = [x for x in d.not_separable if str(x.get("from", "")).startswith(FROM_SETTLED_STREAM)]
    unseen = [x for x in d.not_separable if x.get("from") == FROM_NO_MARKER]
    geometry = [x for x in d.not_separable if x not in echo and x not in stream and x not in unseen]
    if stream:
        parts.append("Not named, proven only weakly while the stream shows the holds settled: "
                     + ", ".join(f"{x['effect']} ({_where_text(x['where'])})" for x in stream) + ".")
    if echo:
        parts.append("Not told apart from the slow actuator's unfinished approach (not named): "
                     + ", ".join(f"{x['effect']} ({_where_text(x['where'])})" for x in echo) + ".")
    if unseen:
        parts.append("Not seen: no marker moves with these at any pose of the session (a joint no tracked link "
                     "hangs on; not tested): " + ", ".join(f"{x['effect']} ({_where_text(x['where'])})" for x in unseen[:5])
                     + (f" and {len(unseen) - 5} more" if len(unseen) > 5 else "") + ".")
    if geometry:
        parts.append("Not separable from the geometry on this design (not tested further): "
                     + ", ".join(f"{x['effect']} ({_where_text(x['where'])})" for x in geometry[:5])
                     + (f" and {len(geometry) - 5} more" if len(geometry) > 5 else "") + ".")
        for name in sorted({x["effect"] for x in geometry} & set(d.advice)):
            parts.append(d.advice[name])
    for name, reasons in d.untried.items():
        parts.append(f"Not tried: {name} where {'; and where '.join(reasons)}.")
    return parts
