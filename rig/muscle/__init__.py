"""Muscles: templates and a character in; fitted muscles and their static shapes per frame out.

Takes a muscle template (`template`, files in `templates/`) and a Character; fits each muscle from the
outside in (`segmentation` of the skin by bone, `ellipsoid` fits, `conform`, `fit.fit_musculature`)
into a `model.MuscleRig`. Per frame, `MuscleRig.static(world)` gives the static (volume-keeping) shape
of every muscle from joint world transforms: action curve (5 CVs), 5 lofted sections x 8 CVs
(`loft`), tone and pose shapes (`pose_shapes`). `loft_attach` attaches points to a muscle's loft;
`shell_params` is what a template says about the skin around a muscle; `simple_arm` is the thesis's
built-in example. Imports rig.base, rig.motion, rig.character."""
