"""Motion: a mocap clip in, a `Clip` out.

Takes BVH, Acclaim ASF/AMC, glTF animations, the project's keyframe TOML and MJCF skeletons
(`mocap.load_clip`, `keyframes`, `gltf_anim`, `mjcf_skeleton`); gives a read-only `clip.Clip` (joint
tree, rest offsets, per-frame local rotations w,x,y,z and translations, Z-up metres). Also retargets a
clip onto another skeleton (`retarget`, joint maps in `presets/`, roles found by `role_map`) and holds
the project's one quaternion module (`quat`). Imports only rig.base."""
