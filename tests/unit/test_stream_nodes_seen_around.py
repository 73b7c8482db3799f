"""A marker or rigid body seen in only part of a window of a stream without holds is reduced to
the window's nodes only where it is seen on both sides of every node: a node outside the span
seen would be the window's polynomial extrapolated, whose bias its weight does not tell.

The stream: the physical simulator's Stewart on a 10 s path at 40 Hz with two rigid bodies
(tests/bodies_alone.py), marker 0 and body T1 hidden over the last 45 % of every window reduced to
nodes: seen in 55 % of the samples, above MIN_SEEN_SHARE, but not around the last node.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from bodies_alone import stewart_bodies_stream

from platkit.calibrate.motion_bodies import bodies_at_samples, body_samples_said
from platkit.calibrate.stream import seen_around_nodes, stream_windows, window_fit
from platkit.io.session import load_session


@pytest.fixture(scope="module")
def occluded(tmp_path_factory):
    sim, _ = stewart_bodies_stream(tmp_path_factory.mktemp("seen_around"))
    s = load_session(sim, quiet=True)
    win = stream_windows(s, raw_samples=0)  # every window reduced to nodes
    markers, bodies = np.array(s.markers, copy=True), np.array(s.bodies, copy=True)
    hidden = []
    for p, a, n, per in win.blocks:
        if per is None:  # a window kept as samples: each sample its own row
            continue
        cut = a + int(np.ceil(0.55 * n))
        markers[cut:a + n, 0] = np.nan
        bodies[cut:a + n, 0] = np.nan
        hidden.append((p, a, n, cut))
    assert len(hidden) >= 5
    return s, replace(s, markers=markers, bodies=bodies), hidden


def test_the_rule_on_one_window():
    t = np.arange(40) / 40.0
    assert seen_around_nodes(t, np.arange(40), 3)
    assert not seen_around_nodes(t, np.arange(22), 3)  # 55 %: the last node beyond the samples seen
    assert not seen_around_nodes(t, np.arange(18, 40), 3)  # the first node before them
    assert seen_around_nodes(t, np.r_[0:10, 30:40], 3)  # a gap between the nodes: interpolated
    assert not seen_around_nodes(t, np.arange(0, 40, 8), 3)  # too few seen (5 of 40)
    # what the rule keeps out: the last node of a 1 Hz motion seen over 55 % of the window is the
    # polynomial extrapolated, far from where the fit of the whole window puts it
    y = 0.03 * np.sin(2 * np.pi * t + 0.3)
    A_all, _ = window_fit(t, 3)
    A_part, _ = window_fit(t, 3, np.arange(22))
    assert abs((A_part @ y[:22])[-1] - (A_all @ y)[-1]) > 0.05


def test_a_marker_seen_in_part_of_a_window_has_no_node_there(occluded):
    s, hid, hidden = occluded
    win = stream_windows(hid, raw_samples=0)
    for p, *_ in hidden:
        assert np.isnan(win.Y[p:p + win.nodes, 0]).all(), (p, win.Y[p:p + win.nodes, 0])
        assert np.isfinite(win.Y[p:p + win.nodes, 1]).all()  # the others as before
    seen = np.isfinite(hid.markers[:, 0]).all(axis=1)
    assert win.n_left_out >= sum(int(seen[a:cut].sum()) for _, a, _, cut in hidden)  # counted, not dropped silently


def test_a_body_seen_in_part_of_a_window_has_no_node_there(occluded):
    s, hid, hidden = occluded
    win = stream_windows(hid, raw_samples=0)
    got = bodies_at_samples(hid, win)["bodies"]
    for p, *_ in hidden:
        assert np.isnan(got[p:p + win.nodes, 0]).all()
        assert np.isfinite(got[p:p + win.nodes, 1]).all()  # T2, seen throughout
    said = body_samples_said(hid, win)
    seen = np.isfinite(hid.bodies[:, 0]).all(axis=1)
    assert said["per_body"]["T1"]["n_seen_too_little"] >= sum(int(seen[a:cut].sum()) for _, a, _, cut in hidden)
    assert said["n_used"] + sum(said[k] for k in ("n_before_second_command", "n_in_start_transient",
                                                  "n_in_windows_left_out", "n_seen_too_little",
                                                  "n_at_samples_with_no_marker")) == said["n_samples"]
