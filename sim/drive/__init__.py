"""Drive: a Clip in; joint world transforms at any times out.

`skeleton.Skeleton` builds a MuJoCo model from the clip's skeleton and poses it (mj_kinematics);
`physics_drive` makes a MuJoCo humanoid follow the clip on a floor; `mjcf_drive` drives a user's own
MJCF model; `motion` samples any of them into a `Motion` at output frames. Imports rig.*; not
sim.jiggle, sim.bake or sim.app."""
