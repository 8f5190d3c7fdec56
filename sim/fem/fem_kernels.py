"""Warp kernels of the FEM reference: the attached vertices driven to their goal, the rest shape set to the goal.

The soft-body solve itself is Newton's (SolverVBD); what jiggle adds per step is (1) the attached (mass 0,
kinematic) vertices put at their goal at the step's end after VBD's forward step has recorded where they
were at its start (so VBD's damping and velocity see them move), and (2) every tet's rest shape (Dm^-1) set to
the goal shape at the step's end, so the body's stress-free shape is the goal (the static shape), as the
particles' springs are at rest on their goals.
"""
from __future__ import annotations

import warp as wp


@wp.kernel
def place_attached(
    # model
    indices: wp.array[wp.int32],
    # control
    goal: wp.array[wp.vec3],
    # out
    q_out: wp.array[wp.vec3],
    reference_out: wp.array[wp.vec3],
):
    """q_out[j] = reference_out[j] = goal[j], j = indices[i]: attached vertex j at its goal (goal: (N,) every
    vertex's goal at the step's end, metres)."""
    i = wp.tid()
    j = indices[i]
    q_out[j] = goal[j]
    reference_out[j] = goal[j]


@wp.kernel
def goal_rest_poses(
    # model
    tets: wp.array2d[wp.int32],
    # control
    goal: wp.array[wp.vec3],
    # out
    poses_out: wp.array[wp.mat33],
):
    """poses_out[t] = Dm^-1 of tet t in the goal shape: Dm = [x1 - x0, x2 - x0, x3 - x0] of goal (N,) metres."""
    t = wp.tid()
    x0 = goal[tets[t, 0]]
    Dm = wp.matrix_from_cols(goal[tets[t, 1]] - x0, goal[tets[t, 2]] - x0, goal[tets[t, 3]] - x0)
    poses_out[t] = wp.inverse(Dm)


def place(indices, goal, q, reference, device) -> None:
    """Launch place_attached over the attached vertices (skipped when there are none)."""
    if indices.shape[0] == 0:
        return
    wp.launch(place_attached, dim=indices.shape[0], inputs=[indices, goal], outputs=[q, reference], device=device)


def rest_poses(tets, goal, poses, device) -> None:
    """Launch goal_rest_poses over all tets (skipped when there are none)."""
    if tets.shape[0] == 0:
        return
    wp.launch(goal_rest_poses, dim=tets.shape[0], inputs=[tets, goal], outputs=[poses], device=device)
