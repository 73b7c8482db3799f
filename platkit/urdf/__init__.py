"""Serial chains from URDF files: safe reading, chain extraction, CasADi forward kinematics.

The route every URDF-described stand takes (the ``urdf`` and ``rotary`` stands):

1. :func:`read_urdf` parses the file safely (no DTD, no entities, no network, no meshes) and
   checks the numbers of every joint, naming the joint and element on error.
2. :func:`serial_chain` picks the joints from a base link to a moving link.
3. :func:`chain_spec` turns the chain into a :class:`platkit.model.PlatformSpec` with a
   closed-form ``forward(u, td) -> (q, X)``.

Joint model, for every actuated joint j of the chain (revolute, continuous, prismatic)::

    theta_j = scale_j * (c_j * u_j - offset_j)

with ``c_j`` the control's unit conversion (1 for 'rad' and 'm', pi/180 for 'deg'), ``offset_j``
in the joint's SI unit (rad or m) and ``scale_j`` dimensionless. A mimic joint follows its master:
``theta = multiplier * theta_master + offset`` (URDF semantics; the master must be an actuated
joint that is a control: on a chain, a joint of the chain; on a tree, a recorded joint anywhere
in it), with the multiplier and offset parameters of their own (group ``mimic``, nominal the
URDF's numbers, fixed unless freed). Each actuated or mimic joint's origin carries a small rigid
error::

    parent_from_child = origin_nominal * Trans(origin_x, origin_y, origin_z)
                        * Rz(origin_rz) Ry(origin_ry) Rx(origin_rx) * motion(theta)

so an error is expressed in the nominal joint frame (the frame the axis is written in). Errors of
fixed joints are not separate parameters: a small error of a fixed joint between two actuated
joints equals an error of the next actuated joint's origin, one before the first actuated joint is
part of the base-to-mocap transform, one after the last is part of the marker positions.

td layout: per actuated or mimic joint, in chain order, ``<joint>.offset``, ``<joint>.scale``
(actuated only) or ``<joint>.mimic_multiplier``, ``<joint>.mimic_offset`` (mimic only), then
``<joint>.origin_x, _y, _z, _rx, _ry, _rz``. Nominal values: offset 0, scale 1, origin errors 0,
the mimic's own numbers; the URDF's own numbers are kept in ``spec.extras['chain']``.

Trees (:func:`kinematic_tree`, :func:`tree_spec`): several links carry markers (two hands on one
torso). The controls are the recorded actuated joints below the base link (every one by
default), in depth-first order; each joint's parameters are laid out as on a chain, in the same
order, and a joint that moves no tracked link keeps its parameters (the identifiability analysis
holds them). The spec's pose is the first tracked link's; ``spec.link_poses`` gives every
tracked link's.
"""
from __future__ import annotations

from platkit.urdf._kinematics import (
    CONTROL_UNIT_FACTORS,
    ORIGIN_FIELDS,
    chain_kinematics,
    chain_parameters,
    chain_spec,
    frame_jacobian,
    joint_origins,
    joint_values,
    link_kinematics,
    link_pose_function,
    orientation_error,
    urdf_rpy,
)
from platkit.urdf._parse import KNOWN_TYPES, MAX_URDF_BYTES, parse_urdf_xml, read_urdf
from platkit.urdf._tree import (
    ACTUATED_TYPES,
    KinematicTree,
    SerialChain,
    UrdfJoint,
    UrdfTree,
    kinematic_tree,
    serial_chain,
)

__all__ = [
    "MAX_URDF_BYTES",
    "ACTUATED_TYPES",
    "KNOWN_TYPES",
    "ORIGIN_FIELDS",
    "CONTROL_UNIT_FACTORS",
    "UrdfJoint",
    "UrdfTree",
    "parse_urdf_xml",
    "read_urdf",
    "SerialChain",
    "serial_chain",
    "KinematicTree",
    "kinematic_tree",
    "chain_parameters",
    "joint_origins",
    "joint_values",
    "chain_kinematics",
    "link_kinematics",
    "orientation_error",
    "chain_spec",
    "frame_jacobian",
    "link_pose_function",
    "urdf_rpy",
]
