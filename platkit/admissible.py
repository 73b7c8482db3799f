"""The admissible set of a stand: the poses it can take with every control inside its stroke and
the mechanism on its branch (Burlakov et al., fig. 4, for the PSVR in (alpha, beta, h)).

Two views of the same set, for any stand:

- :func:`pose_images`: forward kinematics of a grid over the control box (the set is the image
  of the box); gives the extent of the set and a cloud of its points.
- :func:`admissible_grid`: a grid over chosen pose coordinates (the others held fixed); a grid
  pose is admissible when inverse kinematics has a real solution there, every control is inside
  its stroke, the stand's branch function is positive and the constraints close. This is a
  membership test cell by cell, so it gives slices, volumes and boundaries.

Lengths in metres, angles in radians; :func:`plot_slices` and :func:`plot_boundary` draw mm and
degrees.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from platkit.errors import BadInput, ComputationFailed, PlatkitError
from platkit.kinematics import PlatformModel
from platkit.kinematics.sampling import controls_of_poses, nominal_inverse, pose_grid
from platkit.model import PlatformSpec

#: |F| (m) above which a grid pose's inverse is not trusted to close the constraints
CLOSE_TOL = 1e-8
#: a swept coordinate whose admissible values span no more than this (m or rad) is degenerate
DEGENERATE_SPAN = 1e-6


@dataclass
class AdmissibleGrid:
    """Membership of a pose grid in the admissible set.

    ``names``: the swept pose coordinates (k of them); ``axes``: their grid values (SI), one array
    each; ``fixed``: the other coordinates' values (SI). Arrays over the grid have shape
    ``shape = tuple(len(a) for a in axes)``: ``inside`` (bool), ``controls`` (shape + (n_u,), NaN
    where inverse kinematics has no real solution), and the reasons a pose is out:
    ``no_solution``, ``outside_stroke``, ``off_branch`` (bool each).
    """

    platform: str
    names: tuple[str, ...]
    units: tuple[str, ...]
    axes: tuple[np.ndarray, ...]
    fixed: dict[str, float]
    inside: np.ndarray
    controls: np.ndarray
    no_solution: np.ndarray
    outside_stroke: np.ndarray
    off_branch: np.ndarray
    control_names: tuple[str, ...] = field(default=())

    @property
    def shape(self) -> tuple[int, ...]:
        return self.inside.shape

    @property
    def cell_volume(self) -> float:
        """Product of the grid steps (SI units of the swept coordinates multiplied)."""
        return float(np.prod([a[1] - a[0] if len(a) > 1 else 1.0 for a in self.axes]))

    @property
    def volume(self) -> float:
        """Measure of the admissible set in the swept coordinates: admissible cells x cell volume."""
        return float(self.inside.sum()) * self.cell_volume

    def points(self) -> np.ndarray:
        """Admissible grid poses, (N, k) in the swept coordinates (SI)."""
        mesh = np.meshgrid(*self.axes, indexing="ij")
        return np.stack([m[self.inside] for m in mesh], axis=1)

    def extent(self) -> dict[str, tuple[float, float]]:
        """Per swept coordinate, the smallest and largest admissible grid value (SI)."""
        pts = self.points()
        if pts.size == 0:
            return {n: (np.nan, np.nan) for n in self.names}
        return {n: (float(pts[:, i].min()), float(pts[:, i].max())) for i, n in enumerate(self.names)}

    def boundary(self) -> np.ndarray:
        """Admissible cells with a non-admissible (or off-grid) neighbour along some axis, bool."""
        padded = np.pad(self.inside, 1, constant_values=False)
        edge = np.zeros_like(self.inside)
        core = tuple(slice(1, -1) for _ in self.shape)
        for ax in range(self.inside.ndim):
            for step in (-1, 1):
                edge |= ~np.roll(padded, step, axis=ax)[core]
        return self.inside & edge


def control_grid(spec: PlatformSpec, n: int) -> np.ndarray:
    """Every combination of ``n`` evenly spaced values per control over its stroke: (n**n_u, n_u)."""
    lo, hi = spec.control_bounds()
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise BadInput(f"stand {spec.name!r} has a control without a finite stroke; its control box cannot be sampled")
    if n < 2:
        raise BadInput(f"a control grid needs at least 2 values per control, got {n}")
    values = [np.linspace(a, b, n) for a, b in zip(lo, hi)]
    return np.array(list(itertools.product(*values)), dtype=float)


#: most control combinations pose_images solves: n**n_u grows past memory for long chains
#: (TIAGo's 8 joints at 7 values: 5.8 million)
MAX_CONTROL_SAMPLES = 20000


def control_samples(spec: PlatformSpec, n: int, max_samples: int = MAX_CONTROL_SAMPLES, seed: int = 0) -> np.ndarray:
    """The control grid with ``n`` values per control when it has at most ``max_samples`` rows;
    else the finest grid that fits (at least 2 values per control: the box's corners), or, when
    even the corners do not fit, ``max_samples`` seeded uniform draws over the box. (M, n_u)."""
    if n ** spec.n_u <= max_samples:
        return control_grid(spec, n)
    n_fit = int(np.floor(max_samples ** (1.0 / spec.n_u) + 1e-9))
    if n_fit >= 2:
        return control_grid(spec, min(n, n_fit))
    control_grid(spec, 2)  # the same checks of the strokes
    lo, hi = spec.control_bounds()
    return lo + (hi - lo) * np.random.default_rng(seed).random((max_samples, spec.n_u))


def pose_images(spec: PlatformSpec, n: int = 9, td=None, model: PlatformModel | None = None) -> np.ndarray:
    """Pose coordinates (M, n_p) of the control grid's forward solutions that converge on the
    stand's branch (started from the neutral pose). ``n``: values per control (fewer when the
    grid would pass :data:`MAX_CONTROL_SAMPLES` rows; see :func:`control_samples`).

    A stand whose pose space is free (``spec.free_space == 'pose'``; its independent controls
    are almost never consistent) samples that space instead: the poses of a grid over the
    coordinates' bounds (``n`` values per coordinate, fewer past MAX_CONTROL_SAMPLES) whose
    inverse kinematics lies inside the strokes on the branch."""
    model = model or PlatformModel(spec)
    if spec.pose_free:
        k = max(2, min(n, int(np.floor(MAX_CONTROL_SAMPLES ** (1.0 / spec.n_p) + 1e-9))))
        P = pose_grid(spec, k)
        return P[controls_of_poses(model, P, td)["ok"]]
    U = control_samples(spec, n)
    fb = model.forward_batch(U, td=td)
    keep = fb.converged & fb.on_branch
    return np.asarray(fb.p)[keep]


def default_axes(spec: PlatformSpec, names: list[str], n: int, td=None, margin: float = 0.05,
                 model: PlatformModel | None = None, n_controls: int = 7) -> dict[str, np.ndarray]:
    """Grid values for the named coordinates covering the set: the extent of the control box's
    forward images, widened by ``margin`` of the range on each side and clipped to the
    coordinates' own limits. ``n`` values per coordinate."""
    idx = _coordinate_indices(spec, names)
    pts = pose_images(spec, n_controls, td=td, model=model)
    if pts.shape[0] == 0:
        what = "pose of the grid over the pose box" if spec.pose_free else "control combination"
        raise PlatkitError(f"{spec.name}: no {what} has a forward solution on the stand's branch")
    axes = {}
    for name, i in zip(names, idx):
        c = spec.coordinates[i]
        lo, hi = float(pts[:, i].min()), float(pts[:, i].max())
        if not hi - lo > DEGENERATE_SPAN:
            raise ComputationFailed(
                f"{spec.name}: the admissible set is degenerate: pose coordinate {name} spans {hi - lo:.3g} "
                f"{c.unit} over the {pts.shape[0]} sampled poses the stand takes (a point or a sliver); "
                + ("its free space is its pose box (field 'free_space')" if spec.pose_free else
                   "if its commands are not independent (a cable robot), declare free_space='pose'"))
        pad = margin * max(hi - lo, 1e-6)
        lo, hi = max(lo - pad, c.lower), min(hi + pad, c.upper)
        axes[name] = np.linspace(lo, hi, n)
    return axes


def _coordinate_indices(spec: PlatformSpec, names) -> list[int]:
    known = spec.coordinate_names
    bad = [n for n in names if n not in known]
    if bad:
        raise BadInput(f"{spec.name} has no pose coordinate {bad[0]!r}; its coordinates are {', '.join(known)}")
    if len(set(names)) != len(names):
        raise BadInput(f"pose coordinates {list(names)} name one twice")
    return [known.index(n) for n in names]


def admissible_poses(spec: PlatformSpec, P, td=None, model: PlatformModel | None = None) -> dict[str, np.ndarray]:
    """Admissibility of poses ``P`` (N, n_p) in the stand's coordinates (SI).

    Returns arrays over N: ``inside`` (bool), ``controls`` (N, n_u; NaN where inverse kinematics
    has no real solution), and the reasons a pose is out, ``no_solution``, ``outside_stroke``,
    ``off_branch`` (bool; at most one is true per pose). Uses the stand's closed-form inverse
    where it has one (batched), otherwise Gauss-Newton from the neutral controls pose by pose.
    """
    model = model or PlatformModel(spec)
    P = np.atleast_2d(np.asarray(P, float))
    if P.shape[1] != spec.n_p:
        raise BadInput(f"{spec.name} poses have {spec.n_p} coordinates, got {P.shape[1]}")
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    N = P.shape[0]
    U, q, X = nominal_inverse(model, P, td)  # NaN rows: no solution from the neutral start
    no_solution = ~np.all(np.isfinite(U), axis=1)
    Us = np.where(no_solution[:, None], spec.neutral_u(), U)
    r = np.asarray(spec.residual.map(N)(Us.T, td, q.T, X.T)).T
    no_solution |= np.linalg.norm(r, axis=1) > CLOSE_TOL
    lo, hi = spec.control_bounds()
    outside = ~no_solution & np.any((Us < lo - 1e-12) | (Us > hi + 1e-12), axis=1)
    if spec.branch is not None:
        g = np.asarray(spec.branch.map(N)(Us.T, td, q.T, X.T)).T
        off = ~no_solution & ~np.all(g > 0, axis=1)
    else:
        off = np.zeros(N, bool)
    inside = ~(no_solution | outside | off)
    U[no_solution] = np.nan
    return dict(inside=inside, controls=U, no_solution=no_solution, outside_stroke=outside, off_branch=off)


def admissible_grid(spec: PlatformSpec, axes: dict[str, np.ndarray], fixed: dict[str, float] | None = None,
                    td=None, model: PlatformModel | None = None) -> AdmissibleGrid:
    """Test every pose of the grid ``axes`` (coordinate name -> values, SI) for admissibility.

    Coordinates not in ``axes`` take their value in ``fixed`` or else the neutral one. Uses the
    stand's closed-form inverse where it has one (batched), otherwise Gauss-Newton from the
    neutral controls pose by pose.
    """
    model = model or PlatformModel(spec)
    names = list(axes)
    idx = _coordinate_indices(spec, names)
    fixed = dict(fixed or {})
    _coordinate_indices(spec, list(fixed))
    clash = sorted(set(fixed) & set(names))
    if clash:
        raise BadInput(f"pose coordinate {clash[0]!r} is both swept and fixed")
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    grids = [np.asarray(axes[n], float).ravel() for n in names]
    shape = tuple(len(g) for g in grids)
    mesh = np.meshgrid(*grids, indexing="ij")
    P = np.tile(spec.neutral_p(), (int(np.prod(shape)), 1))
    for name, value in fixed.items():
        P[:, spec.coordinate_names.index(name)] = float(value)
    for i, m in zip(idx, mesh):
        P[:, i] = m.ravel()
    test = admissible_poses(spec, P, td=td, model=model)
    inside, U = test["inside"], test["controls"]
    no_solution, outside, off = test["no_solution"], test["outside_stroke"], test["off_branch"]
    units = tuple(spec.coordinates[i].unit for i in idx)
    fixed_all = {c.name: float(P[0, j]) for j, c in enumerate(spec.coordinates) if c.name not in names}
    return AdmissibleGrid(
        platform=spec.name, names=tuple(names), units=units, axes=tuple(grids), fixed=fixed_all,
        inside=inside.reshape(shape), controls=U.reshape(shape + (spec.n_u,)),
        no_solution=no_solution.reshape(shape), outside_stroke=outside.reshape(shape), off_branch=off.reshape(shape),
        control_names=tuple(spec.control_names),
    )


def check_not_degenerate(grid: AdmissibleGrid) -> None:
    """ComputationFailed (one line) when the grid's admissible poses are a point or a sliver:
    fewer than two grid values along some swept coordinate, or a grid whose own range along a
    coordinate is no more than :data:`DEGENERATE_SPAN`."""
    if not grid.inside.any():
        raise ComputationFailed(f"{grid.platform}: no pose of the grid is admissible")
    for k, (name, axis, unit) in enumerate(zip(grid.names, grid.axes, grid.units)):
        occupied = np.unique(np.nonzero(grid.inside)[k])
        span = float(axis[-1] - axis[0]) if len(axis) > 1 else 0.0
        if occupied.size < 2 or not span > DEGENERATE_SPAN:
            raise ComputationFailed(
                f"{grid.platform}: the admissible set is degenerate along {name}: {occupied.size} of {len(axis)} grid "
                f"values over {span:.3g} {unit} hold admissible poses (a point or a sliver, {int(grid.inside.sum())} "
                "poses in all); no volume or boundary is reported")


# ----------------------------------------------------------------------------- plots


def _display(values: np.ndarray, unit: str) -> tuple[np.ndarray, str]:
    if unit == "rad":
        return np.degrees(values), "deg"
    if unit == "m":
        return np.asarray(values) * 1000.0, "mm"
    return np.asarray(values), unit


def plot_slices(grid: AdmissibleGrid, path, n_slices: int = 6) -> list[float]:
    """Draw the admissible set of a 3-coordinate grid as 2-D slices of its first two coordinates at
    ``n_slices`` values of the third (or the one slice of a 2-coordinate grid). Writes a PNG to
    ``path`` (angles in degrees, lengths in mm); returns the sliced values (SI)."""
    from matplotlib.figure import Figure  # bare Figures: no pyplot state; matplotlib only when drawing

    if grid.inside.ndim not in (2, 3):
        raise BadInput(f"slices need 2 or 3 swept coordinates, got {grid.inside.ndim}")
    inside = grid.inside if grid.inside.ndim == 3 else grid.inside[..., None]
    third = grid.axes[2] if grid.inside.ndim == 3 else np.array([np.nan])
    occupied = np.nonzero(inside.any(axis=(0, 1)))[0]
    if occupied.size == 0:
        raise PlatkitError(f"{grid.platform}: no pose of the grid is admissible; nothing to draw")
    # slice at the centres of n equal bands of the occupied range (the extreme slices are single points)
    span = occupied[-1] - occupied[0]
    picks = np.unique((occupied[0] + span * (np.arange(n_slices) + 0.5) / n_slices).round().astype(int))
    x, xu = _display(grid.axes[0], grid.units[0])
    y, yu = _display(grid.axes[1], grid.units[1])
    cols = min(3, len(picks))
    rows = int(np.ceil(len(picks) / cols))
    fig = Figure(figsize=(4.2 * cols, 3.8 * rows))
    axs = fig.subplots(rows, cols, squeeze=False)
    for ax in axs.ravel()[len(picks):]:
        ax.set_visible(False)
    for ax, k in zip(axs.ravel(), picks):
        ax.contourf(x, y, inside[:, :, k].T.astype(float), levels=[0.5, 1.5], colors=["tab:blue"], alpha=0.55)
        ax.contour(x, y, inside[:, :, k].T.astype(float), levels=[0.5], colors=["tab:blue"], linewidths=1.0)
        ax.set_xlim(x[0], x[-1])
        ax.set_ylim(y[0], y[-1])
        ax.set_xlabel(f"{grid.names[0]} [{xu}]")
        ax.set_ylabel(f"{grid.names[1]} [{yu}]")
        if grid.inside.ndim == 3:
            v, vu = _display(third[k], grid.units[2])
            ax.set_title(f"{grid.names[2]} = {float(v):.1f} {vu}")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{grid.platform}: admissible poses")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return [float(third[k]) for k in picks]


def plot_boundary(grid: AdmissibleGrid, path) -> int:
    """3-D scatter of the boundary cells of a 3-coordinate grid, coloured by the third coordinate.
    Writes a PNG to ``path``; returns the number of points drawn."""
    from matplotlib.figure import Figure  # bare Figures: no pyplot state; matplotlib only when drawing

    if grid.inside.ndim != 3:
        raise BadInput(f"a 3-D view needs 3 swept coordinates, got {grid.inside.ndim}")
    mesh = np.meshgrid(*grid.axes, indexing="ij")
    edge = grid.boundary()
    pts = [_display(m[edge], u) for m, u in zip(mesh, grid.units)]
    fig = Figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    sc = ax.scatter(pts[0][0], pts[1][0], pts[2][0], c=pts[2][0], s=4, cmap="viridis", depthshade=False)
    ax.set_xlabel(f"{grid.names[0]} [{pts[0][1]}]")
    ax.set_ylabel(f"{grid.names[1]} [{pts[1][1]}]")
    ax.set_zlabel(f"{grid.names[2]} [{pts[2][1]}]")
    fig.colorbar(sc, ax=ax, shrink=0.6, label=f"{grid.names[2]} [{pts[2][1]}]")
    ax.set_title(f"{grid.platform}: boundary of the admissible set")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return int(edge.sum())
