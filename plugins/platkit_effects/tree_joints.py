"""The elasticity of every loaded joint of a tree session in one term, and the other forms of it
the data must choose between: a joint's compliance or the bending of the link before it.

Rules:

- On a session with several tracked links, one compliance per control whose load changes over the
  poses and that moves a tracked link, fitted together (:class:`JointsComplianceTerm`): a
  humanoid's torso and arms give at many joints at once, and each joint named alone would take one
  of diagnosis's few rounds.
- A joint whose axis passes through its parent joint's pivot across the parent's axis (the joint
  at the parent's origin, a shoulder's roll at its pitch, or out along its own axis from it, TIAGo's
  upper-arm roll 9 cm down the link from the shoulder: a rotation about a line is the same wherever
  along it it is taken; within ``SAME_LINE_M``) turns the links it carries, to first order, as
  the parent's link bending does about that axis; the bending also turns them about the third
  axis. The term offers, as its ``alternatives``, the joint's
  compliance replaced by that bending (one compliance across, or one per axis across), and
  diagnosis keeps a form whose BIC is lower (platkit.diagnose.forms, ``tell_apart``).
- A joint that drives mimic joints (a coupled joint) gives, in the control's compliance, with
  its mimic joints following (an elastic drive ahead of the coupling); the term also offers, as a
  form, its own joint giving alone, the mimic joints held where commanded (``where['alone']``;
  platkit_effects.tree_mimic): left out, the bending of the link below the master takes the
  difference, a name the physics does not hold.
- A URDF without inertias: the loads are the prior of uniform links', whose shape (how the mass
  lies along each branch, how much each branch weighs against the trunk) is not the robot's. The
  term then also offers, as a form, the whole tree's mass moments estimated with the compliances:
  ``pi = pi_prior + B delta`` in every joint's load ``Y_j(q) pi`` and in the moment every bend of
  the term turns under, one ``pi`` for the tree (so an arm's weight is the same in its own joints'
  loads and in the torso's). ``B`` holds the
  combinations that change the deflections in a way no joint's compliance can (the regressor
  weighted by the fitted compliances, its part along each joint's own load projected out: the
  scale the compliances carry), best determined first; each count of ``MASS_STEPS`` offered as a
  form, tried in turn (one that is not kept does not stop a larger one), each kept on a lower BIC;
  ``where`` says how many are identifiable at all.
- The estimate has a prior: ``pi`` Gaussian about ``pi_prior`` with the prior of uniform links'
  spread (platkit.tree_loads, ``prior_spread``: each body's mass to 100 % of its prior mass, its
  first moments to that times its length), independent. ``B``'s combinations are taken in that
  prior's metric (the regressor's columns scaled by the spreads before the SVD: best determined
  against the prior first), each column one prior standard deviation, so that the prior on
  ``delta`` is ``N(0, I)`` and enters the estimator as one row ``sigma delta_k`` per combination
  beside the marker residuals (ModelTerm.prior, the rows of the calibration's ridge; sigma the
  marker noise per coordinate: the session's settled noise where it says it, else
  ``MASS_PRIOR_NOISE_M``, 0: no rows, the basis still taken in the prior's metric). With rows, a
  combination the data barely see stays near the prior instead of wandering.
  The BIC that keeps a count scores that fit's marker residuals (the prior's rows left
  out) with every combination a whole parameter: a combination the prior holds costs its whole
  log n and buys little fit, so a larger count is kept only for what the data determine beyond
  the prior (conservative: the data's share of each combination, an effective count, would
  charge it less).
- Stored with its standard deviations (calibration.yaml, diagnosis.json's finding), the term says
  in ``where['mass_prior']`` each combination's posterior standard deviation (in prior standard
  deviations), how many the data determine beyond the prior (posterior below ``DETERMINED``
  of the prior's: the data weigh more than the prior), and where the estimate is not physical: a
  body whose implied mass is negative, or whose centre lies beyond twice its length, by more than
  two posterior spreads, where the data moved it (its mass's posterior spread below its prior's).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from platkit.effects import stored_where
from platkit.errors import BadInput
from platkit.model import PlatformSpec
from platkit.terms import ModelTerm
from platkit.tree_loads import PRIOR_SPREAD
from platkit_effects.tree_compliance import (
    LINEAR_LIMIT,
    RANK_TOL,
    JointRotationTerm,
    TreeStand,
    _stand_where,
    across_axes,
    deflected_slope,
    deflected_torque,
    joint_rotation_from_dict,
    joint_rotation_term,
    load_state,
    marker_points,
    moved_by,
    spec_from_where,
    tree_stand,
)
from platkit_effects.tree_mimic import coupled, coupled_offsets, held_mimic_offsets

#: the tree's mass-moment combinations the every-joint term's forms estimate in turn (no inertias)
MASS_STEPS = (4, 8, 16)
#: marker noise per coordinate (m) the mass moments' prior is weighed against where the session
#: does not say its own: 0, no prior rows (with 0.1 mm, a motion-capture system's typical noise,
#: the rows predicted Talos's unseen seed 24803 0.05 mm worse per hand than without them)
MASS_PRIOR_NOISE_M = 0.0
#: how far (m) a joint's axis may pass from its parent's pivot and still turn the links as the
#: parent's bending does about that axis: the two differ by the turn times the distance (2 mm at
#: 5 mrad: 10 um, a tenth of a motion-capture system's typical noise)
SAME_LINE_M = 2e-3
#: a combination whose posterior standard deviation is below this share of its prior's is
#: determined by the data (their information exceeds the prior's)
DETERMINED = 1.0 / np.sqrt(2.0)


def marker_noise(poses) -> float:
    """The marker noise per coordinate (m) of a settled pose of ``poses``: the settling search's
    sigma over the root of the samples averaged, where the session says them; else
    MASS_PRIOR_NOISE_M."""
    sigma = (getattr(poses, "settling", None) or {}).get("sigma_m")
    n = getattr(poses, "n_samples", None)
    if sigma is None or n is None or not np.any(np.asarray(n, float) > 0):
        return MASS_PRIOR_NOISE_M
    n = np.asarray(n, float)
    return float(sigma) / float(np.sqrt(np.mean(n[n > 0])))


@dataclass
class JointsComplianceTerm(ModelTerm):
    """The elasticity of many joints of a tree at once: control ``indices[k]`` (tree joint
    ``joints[k]``) offset by ``theta_k tau_k``, each load at its joint's own deflected
    configuration (:func:`deflected_torque`); theta in the control's unit per N m (N). Then, one
    parameter each, the link bending of ``bends`` (:class:`JointRotationTerm`, 'across'): a
    joint's compliance the data told apart as its parent's bending (:meth:`alternatives`). Last,
    on a URDF without inertias, ``masses`` (4 J, K): the tree's mass moments' change from the
    prior's, ``B delta``, one parameter per column, added to every joint's load (``Y_j B delta``,
    at the deflected configuration to the same first order) and to the moment each bend turns
    under (``M_b B delta``, M_b the moment's regressor at its joint)."""

    indices: list[int] = field(default_factory=list)
    joints: list[str] = field(default_factory=list)
    spec: PlatformSpec | None = field(default=None, repr=False)
    bends: list[JointRotationTerm] = field(default_factory=list)
    masses: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)
    noise_m: float = MASS_PRIOR_NOISE_M

    def prior(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The mass moments' prior (module docstring): ``N(0, 1)`` on each delta, weighed against
        the marker noise ``noise_m``; none on the compliances and bends."""
        if not self.n_masses:
            return None
        n = len(self.parameter_names)
        weight = np.zeros(n)
        weight[n - self.n_masses:] = self.noise_m
        return np.zeros(n), weight

    def to_dict(self, theta, std=None) -> dict:
        """As ModelTerm's; with ``std`` and mass moments, ``where['mass_prior']`` (the same dict
        object as the term's, which a finding's copy of ``where`` shares) filled in with the
        estimate's posterior against its prior (:meth:`mass_estimate`)."""
        if self.n_masses and std is not None and "mass_prior" in self.where:
            self.where["mass_prior"].update(self.mass_estimate(np.asarray(theta, float), np.asarray(std, float)))
        return super().to_dict(theta, std)

    def mass_estimate(self, theta: np.ndarray, std: np.ndarray) -> dict:
        """The mass moments' estimate against its prior: each combination's posterior standard
        deviation in prior standard deviations, the count below DETERMINED, and the bodies (by
        the joint that carries them) where the implied ``pi_prior + B delta`` is not physical
        while the data moved it (mass posterior spread below its prior's), each by more than two
        posterior spreads: a negative mass ([kg, its spread], in the prior's scale: the
        compliances carry the overall size), a centre (m) beyond twice the body's length."""
        K = self.n_masses
        stand = self.stand()
        T = stand.loads
        delta, sd = theta[len(theta) - K:], np.abs(std[len(std) - K:])
        pi = (T.mass_moments() + self.masses @ delta).reshape(-1, 4)
        spread = T.prior_spread().reshape(-1, 4)
        sd_pi = np.sqrt(((self.masses * sd) ** 2).sum(axis=1)).reshape(-1, 4)  # combinations taken apart
        moved = np.isfinite(sd_pi[:, 0]) & (sd_pi[:, 0] < spread[:, 0])
        length = np.where(spread[:, 0] > 0, spread[:, 1] / np.where(spread[:, 0] > 0, spread[:, 0], 1.0), 0.0)
        negative = {T.joints[j]: [round(float(pi[j, 0]), 6), round(float(sd_pi[j, 0]), 6)]
                    for j in np.nonzero(moved & (pi[:, 0] + 2 * sd_pi[:, 0] < 0))[0]}
        far = {}  # the first moment beyond twice the length times the mass by two of its spreads
        for j in np.nonzero(moved & (pi[:, 0] > 0))[0]:
            beyond = np.linalg.norm(pi[j, 1:]) - 2 * length[j] * pi[j, 0]
            if beyond > 2 * np.linalg.norm(sd_pi[j, 1:]):
                far[T.joints[j]] = round(float(np.linalg.norm(pi[j, 1:]) / pi[j, 0]), 6)
        post = [None if not np.isfinite(v) else round(float(v), 4) for v in sd]
        return {"posterior_std": post, "determined_by_data": int(np.sum(np.isfinite(sd) & (sd < DETERMINED))),
                "negative_masses_kg": negative, "centres_beyond_twice_length_m": far,
                "physical": not negative and not far}

    def stand(self) -> TreeStand:
        if self.spec is None:
            self.spec = spec_from_where(self.where, self.effect)
        stand = tree_stand(self.spec)
        if stand is None or any(n not in stand.loads.index for n in self.joints):
            raise BadInput(f"effect {self.effect!r}: joints {', '.join(self.joints)} are not all moving joints "
                           "of the stand's URDF")
        return stand

    @property
    def n_masses(self) -> int:
        return int(self.masses.shape[1]) if self.masses.size else 0

    def _mass_loads(self, theta, controls) -> tuple[np.ndarray, np.ndarray]:
        """((N, J_t) each joint's load change ``Y_j B delta``, (N, J_t, K) per unit of each delta)."""
        K = self.n_masses
        N = len(np.atleast_2d(controls))
        if not K:
            return np.zeros((N, len(self.joints))), np.zeros((N, len(self.joints), 0))
        stand = self.stand()
        Y = load_state(stand, controls).torque_regressor(stand)[:, [stand.loads.index[n] for n in self.joints]]
        per = Y @ self.masses
        return per @ np.asarray(theta[-K:], float), per

    def _gain(self, stand, controls, joint: str, c_si: float) -> np.ndarray:
        """(N,) the deflected configuration's factor on a load change, ``1 / (1 - c g)`` (1 where
        ``|c g|`` passes LINEAR_LIMIT: there the change is taken at the commands)."""
        cg = c_si * load_state(stand, controls).slope(stand, joint)
        if c_si == 0 or np.max(np.abs(cg), initial=0.0) > LINEAR_LIMIT:
            return np.ones(len(cg))
        return 1.0 / (1.0 - cg)

    def control_offset(self, theta, poses, n_u):
        """Each control's deflection under its own load (:meth:`_own_offset`), each load taken
        where the other joints of the term have given too, to first order
        (tree_mimic.coupled_offsets)."""
        own = self._own_offset(theta, poses, n_u)
        return own + coupled_offsets(self.stand(), poses.controls, self.indices, self.joints, self.alone, theta, own)

    def _own_offset(self, theta, poses, n_u):
        """Each control's deflection under its own load at its own deflected configuration."""
        stand = self.stand()
        out = np.zeros((poses.n_poses, n_u))
        extra, _ = self._mass_loads(theta, poses.controls)
        for k, (c, i, n) in enumerate(zip(theta, self.indices, self.joints)):
            tau = deflected_torque(stand, poses.controls, n, c * stand.scale[i])
            if self.n_masses:
                tau = tau + extra[:, k] * self._gain(stand, poses.controls, n, c * stand.scale[i])
            out[:, i] = c * tau
        return out

    def _bent(self, theta) -> list[tuple[slice, np.ndarray, JointRotationTerm]]:
        """(columns, parameters, term) of each bend, after the compliances."""
        out, k = [], len(self.indices)
        for b in self.bends:
            K = len(b.parameter_names)
            out.append((slice(k, k + K), np.asarray(theta[k:k + K], float), b))
            k += K
        return out

    def _bend_moments(self, theta, controls) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per bend, (the moment's change ``M_b B delta`` (N, 3), per unit of each delta (N, 3, K)) at
        its joint in its frame: the bends turn under the tree's estimated loads too."""
        stand = self.stand()
        R = load_state(stand, controls).moment_regressor(stand)
        deltas = np.asarray(theta[len(theta) - self.n_masses:], float)
        out = []
        for b in self.bends:
            per = R[:, stand.loads.index[b.joint]] @ self.masses
            out.append((per @ deltas, per))
        return out

    @property
    def alone(self) -> list[str]:
        """The joints of the term whose elasticity is their own joint's alone, their mimic joints
        held where commanded (``where['alone']``; platkit_effects.tree_mimic)."""
        return [n for n in self.where.get("alone") or [] if n in self.joints]

    def _held(self, theta, poses, fk_X) -> tuple[np.ndarray, np.ndarray]:
        """The offsets that hold the mimic joints of :attr:`alone` (tree_mimic.held_mimic_offsets)."""
        stand = self.stand()
        D = self.control_offset(theta, poses, stand.spec.n_u)[:, self.indices] * stand.scale[self.indices]
        return held_mimic_offsets(self.spec, stand, self.joints, self.alone, D, poses, fk_X)

    def pose_offset(self, theta, poses, fk_q, fk_X):
        out = np.zeros((poses.n_poses, 6))
        for _, t, b in self._bent(theta):
            out += b.pose_offset(t, poses, fk_q, fk_X)
        if self.n_masses:
            for (_, t, b), (dM, _) in zip(self._bent(theta), self._bend_moments(theta, poses.controls)):
                out += b.turned(t, dM, poses, fk_X)[0]
        if self.alone:
            out += self._held(theta, poses, fk_X)[0]
        return out

    def marker_offset(self, theta, poses):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        for _, t, b in self._bent(theta):
            out += b.marker_offset(t, poses)
        if self.n_masses:
            for (_, t, b), (dM, _) in zip(self._bent(theta), self._bend_moments(theta, poses.controls)):
                out += b.turned(t, dM, poses, None)[1]
        if self.alone:
            out += self._held(theta, poses, None)[1]
        return out

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        stand = self.stand()
        N, K = poses.n_poses, len(theta)
        control, pose = np.zeros((N, n_u, K)), np.zeros((N, 6, K))
        marker = np.zeros((N, poses.n_markers, 3, K))
        extra, per = self._mass_loads(theta, poses.controls)
        K = self.n_masses
        for k, (c, i, n) in enumerate(zip(theta, self.indices, self.joints)):
            control[:, i, k] = deflected_slope(stand, poses.controls, n, c * stand.scale[i])
            if K:
                gain = self._gain(stand, poses.controls, n, c * stand.scale[i])
                control[:, i, k] += extra[:, k] * gain ** 2
                control[:, i, len(theta) - K:] = c * gain[:, None] * per[:, k]
        control += coupled_offsets(stand, poses.controls, self.indices, self.joints, self.alone, theta,
                                   self._own_offset(theta, poses, n_u), control)[1]
        for cols, t, b in self._bent(theta):
            _, pose[..., cols], marker[..., cols] = b.offset_jacobians(t, poses, n_u, fk_q, fk_X)
        if K:
            for (cols, t, b), (dM, per) in zip(self._bent(theta), self._bend_moments(theta, poses.controls)):
                for m in range(len(t)):  # the bend's compliances under the moment's change
                    unit = np.zeros(len(t))
                    unit[m] = 1.0
                    p, q = b.turned(unit, dM, poses, fk_X)
                    pose[..., cols.start + m] += p
                    marker[..., cols.start + m] += q
                for k in range(K):  # each delta through the bend
                    p, q = b.turned(t, per[..., k], poses, fk_X)
                    pose[..., len(theta) - K + k] += p
                    marker[..., len(theta) - K + k] += q
        for col in range(len(theta)) if self.alone else ():  # the mimic joints held: linear in the deflections
            D = control[:, self.indices, col] * stand.scale[self.indices]
            if np.any(D):
                p, q = held_mimic_offsets(self.spec, stand, self.joints, self.alone, D, poses, fk_X)
                pose[..., col] += p
                marker[..., col] += q
        return control, pose, marker

    def _given_back(self, stand, poses, start: np.ndarray) -> list[tuple[str, ModelTerm]]:
        """This term with the compliance of a joint it lacks given back beside the bending of that
        joint's parent, for each joint whose axis passes through the pivot of a parent this term bends
        (:func:`same_place_parent`) and holds a load that changes over the poses: a joint and the
        link before it may both give (a compliance told apart as the bending took the joint's
        place; the two differ once the parent turns). Its start: the fitted values, the joint's
        compliance zero."""
        out = []
        mine = {b.joint for b in self.bends}
        S = load_state(stand, poses.controls) if mine else None
        for i, n in enumerate(stand.joints):
            if not mine or i in self.indices or n not in stand.loads.index \
                    or not np.ptp(S.loads.torque[:, stand.loads.index[n]]) > 1e-6:
                continue
            parent = same_place_parent(stand, poses.controls, n)
            if parent not in mine:
                continue
            indices = sorted([*self.indices, i])
            at = indices.index(i)
            alt = joints_compliance_term(self.effect, self.spec, indices, self.bends, label=self.where.get("joint"),
                                         masses=self.masses, identifiable=self.where.get("identifiable_mass_moments"),
                                         noise_m=self.noise_m)
            alt.initial = np.insert(np.asarray(start, float), at, 0.0)
            out.append((f"{n}'s compliance given back beside the link bending at {parent}", alt))
        return out

    def alternatives(self, theta, poses, others) -> list[tuple[str, ModelTerm]]:
        """This term with one joint's compliance replaced by its parent joint's link bending, for each
        joint whose axis passes through its parent's pivot across the parent's axis (to first order the
        two turn the links the joint carries about the same line under nearly the same load; the
        bending turns them about the third axis too), in two forms: one compliance
        across (as many parameters), one per axis across (a link stiffer one way than the other:
        one more). As (what changed, the term), its start the fitted values, the bending's from the
        compliance. Not where ``others`` (the model's other terms) bend there already, or where
        the parent cannot be bent on the session (:func:`partial_bending_ok`). On a URDF without
        inertias, first the tree's mass moments estimated with the compliances (each count of
        MASS_STEPS), then, once they are, the bending of each joint that carries every tracked
        link under the estimated loads (one compliance across; beside another term's bend there,
        which turns under the prior's). Before the joints told apart: a compliance told apart
        given back beside its parent's bending (:meth:`_given_back`); after each joint's two
        forms, its parent's bending added beside its compliance (once per parent; the two differ
        once the parent turns)."""
        stand = self.stand()
        bent_already = {str(t.where.get("joint")) for t in others if t.effect == "link_bending"}
        bent_already |= {b.joint for b in self.bends}
        out = []
        K, nb = self.n_masses, len(self.parameter_names) - len(self.indices) - self.n_masses
        start = np.asarray(theta, float)
        deltas = start[len(start) - K:] if K else np.zeros(0)
        scales = np.array([stand.scale[i] for i in self.indices])
        offered = K
        for step in (k for k in MASS_STEPS if k > K and stand.loads.prior):  # the tree's mass moments, each count
            basis, rank = tree_mass_basis(stand, poses.controls, self.joints, start[:len(self.indices)] * scales, step)
            if basis.shape[1] <= offered:
                break
            offered = basis.shape[1]
            alt = joints_compliance_term(self.effect, self.spec, self.indices, self.bends, label=self.where.get("joint"),
                                         masses=basis, identifiable=rank, noise_m=marker_noise(poses))
            was = self.masses @ deltas if K else np.zeros(basis.shape[0])
            spread = stand.loads.prior_spread()  # the last form's change in the prior's metric
            spread = np.where(spread > 0, spread, 1.0)
            alt.initial = np.concatenate([start[:len(start) - K],
                                          np.linalg.lstsq(basis / spread[:, None], was / spread, rcond=None)[0]])
            out.append((f"the tree's mass moments estimated with the compliances ({offered} combinations)", alt))
        if K:  # the trunk's bending under the estimated loads (beside a bend under the prior's, if another term has one)
            S = load_state(stand, poses.controls)
            for n in stand.shared:
                j = stand.loads.index[n]
                if n in {b.joint for b in self.bends} or n not in moved_by(stand) \
                        or not np.max(np.ptp(S.loads.moment[:, j] @ across_axes(stand.loads.axes[j]).T, axis=0)) > 1e-6:
                    continue
                bend = joint_rotation_term("link_bending", self.spec, n, "across")
                alt = joints_compliance_term(self.effect, self.spec, self.indices, self.bends + [bend],
                                             label=self.where.get("joint"), masses=self.masses,
                                             identifiable=self.where.get("identifiable_mass_moments"), noise_m=self.noise_m)
                alt.initial = np.concatenate([start[:len(start) - K], [0.0], deltas])
                out.append((f"link bending at {n} under the tree's estimated loads", alt))
        out += self._given_back(stand, poses, start)
        beside: set[str] = set()
        for k, (i, n) in enumerate(zip(self.indices, self.joints)):
            parent = same_place_parent(stand, poses.controls, n)
            if parent is None or parent in bent_already or (parent not in stand.shared
                                                            and not partial_bending_ok(poses)):
                continue
            keep = [m for m in range(len(self.indices)) if m != k]
            points = marker_points(stand, poses) if parent not in stand.shared else None
            for about, what in (("across", ""), ("across2", ", stiffer one way than the other")):
                bend = joint_rotation_term("link_bending", self.spec, parent, about, points)
                alt = joints_compliance_term(self.effect, self.spec, [self.indices[m] for m in keep],
                                             self.bends + [bend], label=self.where.get("joint"),
                                             masses=self.masses, identifiable=self.where.get(
                                                 "identifiable_mass_moments"), noise_m=self.noise_m)
                alt.initial = np.concatenate([start[keep], start[len(self.indices):len(self.indices) + nb],
                                              np.full(len(bend.parameter_names), start[k] * stand.scale[i]), deltas])
                out.append((f"{n}'s compliance told apart as link bending at {parent}{what}", alt))
            if parent not in beside:  # both give: the bending added, every compliance kept
                beside.add(parent)
                bend = joint_rotation_term("link_bending", self.spec, parent, "across", points)
                alt = joints_compliance_term(self.effect, self.spec, self.indices, self.bends + [bend],
                                             label=self.where.get("joint"), masses=self.masses, identifiable=self.where.get(
                                                 "identifiable_mass_moments"), noise_m=self.noise_m)
                alt.initial = np.concatenate([start[:len(start) - K], [0.0], deltas])
                out.append((f"link bending at {parent} beside {n}'s compliance", alt))
        for n in self.joints:  # a coupled joint's elasticity in its own joint alone, its mimic joints held
            if n not in self.alone and coupled(stand, n):
                alt = replace(self, where={**self.where, "alone": self.alone + [n]}, initial=start.copy())
                out.append((f"{n}'s compliance in its own joint alone, its mimic joints held where commanded", alt))
        for m, b in enumerate(self.bends):  # a bend told apart: the same, stiffer one way than the other
            if b.about == "across":
                two = joint_rotation_term("link_bending", self.spec, b.joint, "across2", b.points)
                alt = joints_compliance_term(self.effect, self.spec, self.indices, self.bends[:m] + [two]
                                             + self.bends[m + 1:], label=self.where.get("joint"), masses=self.masses,
                                             identifiable=self.where.get("identifiable_mass_moments"), noise_m=self.noise_m)
                cols = self._bent(theta)
                alt.initial = np.concatenate([np.asarray(theta[:len(self.indices)], float)]
                                             + [np.repeat(t, 2) if q == m else t for q, (_, t, _) in enumerate(cols)]
                                             + [deltas])
                out.append((f"link bending at {b.joint}, stiffer one way than the other", alt))
        for _, t in out:  # every other form keeps the joints this one turns alone
            if self.alone and isinstance(t, JointsComplianceTerm) and "alone" not in t.where:
                t.where["alone"] = [n for n in self.alone if n in t.joints]
        return out



def tree_mass_basis(stand: TreeStand, controls: np.ndarray, joints: list[str], compliances: np.ndarray,
                    count: int) -> tuple[np.ndarray, int]:
    """(B (4 J, r), rank): the tree's mass-moment combinations that change the deflections of
    ``joints`` (compliances ``compliances``, rad/(N m), as fitted on the prior's loads) in a way no
    joint's compliance can: the torque regressor of each joint weighted by its compliance, its
    part along each joint's own prior load projected out, its columns scaled by the prior's spread
    (TreeLoads.prior_spread: S), the ``count`` best-determined right singular directions v (r <=
    count), each column ``S v``: one prior standard deviation, ``B^T S^-2 B = I`` (the prior on
    delta N(0, I)). rank: how many are identifiable at all (singular values above RANK_TOL of the
    largest). All compliances zero: the joints weighed alike. Loads with no prior spread (a URDF
    with inertias): S = 1."""
    S = load_state(stand, controls)
    cols = [stand.loads.index[n] for n in joints]
    Y = S.torque_regressor(stand)[:, cols]                 # (N, J_t, P)
    N, J, P = Y.shape
    tau = Y @ stand.loads.mass_moments()                    # the prior's loads
    w = np.abs(np.asarray(compliances, float))
    w = np.ones(J) if not np.any(w) else w
    spread = stand.loads.prior_spread()
    spread = np.where(spread > 0, spread, 1.0) if np.any(spread > 0) else np.ones(P)
    A = (Y * w[None, :, None]).reshape(N * J, P)
    C = np.zeros((N, J, J))
    C[:, np.arange(J), np.arange(J)] = tau * w
    Q, _ = np.linalg.qr(C.reshape(N * J, J))
    A = A - Q @ (Q.T @ A)
    if not np.any(A):
        return np.zeros((P, 0)), 0
    _, s, Vt = np.linalg.svd(A * spread[None, :], full_matrices=False)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    return spread[:, None] * Vt[:min(rank, count)].T, rank


def partial_bending_ok(poses) -> bool:
    """Whether a joint that carries only some tracked links can be bent on ``poses``: its markers
    mapped to their links, no rigid bodies (a body's orientation is no marker offset)."""
    return bool(poses.marker_links) and not poses.n_bodies


def same_place_parent(stand: TreeStand, controls: np.ndarray, joint: str, tol_m: float = SAME_LINE_M,
                      across_tol: float = 0.1) -> str | None:
    """The moving joint before ``joint`` on its way to the root when ``joint``'s axis passes through
    the parent's pivot (the line within ``tol_m``; the joint at the parent's origin, or out along
    its own axis from it: a rotation about that line is the same wherever along it it is taken)
    with its axis across the parent's (|cos| below ``across_tol``) and the parent's moment across
    its axis changes over ``controls``; else None."""
    T = stand.loads
    link, parent = T.tree.joints[joint].parent, None
    while link in T.tree.parent_joint:
        j = T.tree.parent_joint[link]
        if j in T.index:
            parent = j
            break
        link = T.tree.joints[j].parent
    if parent is None or parent not in moved_by(stand):
        return None
    S = load_state(stand, controls)
    a, b = T.index[joint], T.index[parent]
    axis_j = np.einsum("nab,b->na", S.loads.rotation[:, a], T.axes[a])
    axis_p = np.einsum("nab,b->na", S.loads.rotation[:, b], T.axes[b])
    axis_j /= np.linalg.norm(axis_j, axis=1, keepdims=True)
    d = S.loads.pivot[:, a] - S.loads.pivot[:, b]
    off_line = d - np.sum(d * axis_j, axis=1, keepdims=True) * axis_j
    if np.linalg.norm(off_line, axis=1).max() > tol_m \
            or np.abs(np.sum(axis_j * axis_p, axis=1)).max() / np.linalg.norm(T.axes[b]) > across_tol:
        return None
    across = S.loads.moment[:, b] @ across_axes(T.axes[b]).T
    return parent if np.max(np.ptp(across, axis=0)) > 1e-6 else None


def joints_compliance_term(effect: str, spec: PlatformSpec, indices: list[int],
                           bends: list[JointRotationTerm] | None = None, label: str | None = None,
                           masses: np.ndarray | None = None, identifiable: int | None = None,
                           noise_m: float = MASS_PRIOR_NOISE_M) -> JointsComplianceTerm:
    """The compliance of the controls ``indices``, then the link bending of ``bends``, then the
    tree's mass moments' change along the columns of ``masses`` (4 J, K) (a URDF without
    inertias; ``identifiable``: how many combinations the session determines at all; ``noise_m``:
    the marker noise their prior is weighed against, module docstring); ``label``
    the place's name (``where['joint']``: a term told apart keeps the place it was named at)."""
    stand = tree_stand(spec)
    if stand is None:
        raise BadInput(f"effect {effect!r}: the stand has no URDF")
    bends = list(bends or [])
    joints = [stand.joints[i] for i in indices]
    units = [f"{spec.controls[i].unit}/({'N' if spec.controls[i].unit == 'm' else 'N m'})" for i in indices]
    where = {"joint": label or f"every loaded joint ({len(indices)})", "joints": joints,
             "actuators": [spec.control_names[i] for i in indices], "actuator_indices": list(indices),
             "load": "gravity torque of the whole tree about each joint's axis, from "
                     + ("the prior of uniform links (the URDF has no inertias)" if stand.loads.prior else "the URDF inertias")}
    if bends:
        where["bends"] = [b.joint for b in bends]
        where["bends_about"] = [b.about for b in bends]
        points = {n: v for b in bends for n, v in b.where.get("marker_points", {}).items()}
        if points:
            where["marker_points"] = points
    masses = np.zeros((0, 0)) if masses is None or not np.size(masses) else np.asarray(masses, float)
    K = masses.shape[1] if masses.size else 0
    if K:
        if masses.shape[0] != 4 * len(stand.loads.joints):
            raise BadInput(f"effect {effect!r}: where.mass_basis must have 4 rows per moving joint of the stand's URDF")
        where["load"] += ", the tree's mass moments estimated with the compliances"
        where["mass_basis"] = np.round(masses, 12).tolist()
        where["identifiable_mass_moments"] = int(identifiable if identifiable is not None else K)
        where["mass_prior"] = {"noise_m": float(noise_m), "prior_std": 1.0,
                               "rule": f"each body's mass to {PRIOR_SPREAD:g} of its prior mass (at least the mean "
                                       "body's), its first moments to that times its length; each combination one "
                                       "prior standard deviation"}
    where.update(_stand_where(spec))
    names = [f"compliance_{spec.control_names[i]}" for i in indices] + \
        [f"bending_{b.joint}" + (f"_{p.rsplit('_', 1)[1]}" if b.about == "across2" else "")
         for b in bends for p in b.parameter_names] + [f"mass_moments_{k + 1}" for k in range(K)]
    units += ["rad/(N m)"] * (len(names) - len(units) - K) + ["prior standard deviations"] * K
    return JointsComplianceTerm(effect, names, np.zeros(len(names)), units, where, indices=list(indices),
                                joints=joints, spec=spec, bends=bends, masses=masses, noise_m=float(noise_m))


def joints_compliance_from_dict(effect: str, data: dict, spec: PlatformSpec | None) -> JointsComplianceTerm:
    where = stored_where(data)
    try:
        indices = [int(i) for i in where["actuator_indices"]]
        bent = [str(n) for n in where.get("bends") or []]
        abouts = [str(a) for a in where.get("bends_about") or ["across"] * len(bent)]
    except (KeyError, TypeError, ValueError):
        raise BadInput(f"effect {effect!r}: where needs actuator_indices (the controls' indices)") from None
    if spec is None:
        spec = spec_from_where(where, effect)
    if not all(0 <= i < spec.n_u for i in indices):
        raise BadInput(f"effect {effect!r}: where.actuator_indices {indices} are not all controls of the stand")
    if len(abouts) != len(bent):
        raise BadInput(f"effect {effect!r}: where.bends_about must give each of where.bends its form")
    bends = [joint_rotation_from_dict("link_bending", {"where": {"joint": n, "about": a,
                                                                 "marker_points": where.get("marker_points") or {}}},
                                      spec) for n, a in zip(bent, abouts)]
    try:
        masses = np.asarray(where.get("mass_basis") or np.zeros((0, 0)), float)
    except (TypeError, ValueError):
        raise BadInput(f"effect {effect!r}: where.mass_basis must be a matrix (4 rows per moving joint)") from None
    if masses.size and masses.ndim != 2:
        raise BadInput(f"effect {effect!r}: where.mass_basis must be a matrix (4 rows per moving joint)")
    try:
        noise = float((where.get("mass_prior") or {}).get("noise_m", MASS_PRIOR_NOISE_M))
    except (AttributeError, TypeError, ValueError):
        raise BadInput(f"effect {effect!r}: where.mass_prior.noise_m must be a marker noise in metres") from None
    if masses.size and not (np.isfinite(noise) and noise >= 0):
        raise BadInput(f"effect {effect!r}: where.mass_prior.noise_m must be a marker noise in metres (0: no prior)")
    term = joints_compliance_term(effect, spec, indices, bends, label=where.get("joint"), masses=masses,
                                  identifiable=where.get("identifiable_mass_moments"), noise_m=noise)
    alone = where.get("alone") or []
    if not isinstance(alone, list) or not all(isinstance(n, str) and n in term.joints and coupled(term.stand(), n)
                                              for n in alone):
        raise BadInput(f"effect {effect!r}: where.alone must list joints of where.joints that drive mimic joints")
    if alone:
        term.where["alone"] = list(alone)
    term.stand()
    return term
