"""Fit a musculoskeletal template to a character from the outside in (Pratscher et al. 2005, section 3).

    character --segment_skin--> a region of skin per bone segment (normal test, low-frequency normals)
    template  --roles-------->  per muscle: the template bone's region, cut to its span along the bone
                                and sector about it, split by the pair's partition plane, or into
                                strips for a multi-belly muscle
              --fit_ellipsoid-> best-fit ellipsoid of the region's triangles
              --attachments-->  origin, hinges, insertion, each a point riding its own bone
              --conform------>  the ellipsoid's mesh inflated toward the skin (embree rays)
              --build_muscle_rig--> the thesis muscle (action curve, 5 x 8 section CVs, loft)

Template bones name roles (rig.motion.retarget.ROLES) that rig.motion.role_map maps onto the character's joints. A
template bone may span several skeleton bones (CMU's spine has three joints between the hips and the
chest): its region is the union of their regions and its frame is the straight line between the two
joints. A skin triangle belongs to the region of the majority of its corners.

Attachment defaults (where the template gives no joint or position): the origin sits at the bone's
start and rides the bone's start joint; the insertion sits at the bone's end and rides its end joint;
the hinges sit at the ends of the fitted ellipsoid's major axis and ride the bone's start joint. A
relative position (x, y, z) is start + L (x e_along + y e_front + z e_side) in the bone's frame at bind
(L its length; e_front the character's front made perpendicular to the bone, e_side = e_along x
e_front); an absolute one is a world point at bind (metres, Z-up).

Multi-belly muscles (thesis 5.1) are N fusiform bellies side by side: the region is cut into N strips
of equal area across the bone (along the region's principal direction most perpendicular to it); each
strip gets its own ellipsoid and origin (its major-axis end nearest the bone's start, riding the
origin joint), and all share the template's insertion and attributes, the one main control.
Fat ("fake") muscles are fitted the same way to their patch of skin; their `depth` is the least
half-thickness, and a patch thinner than that is pushed inward so its outer side stays at the skin.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.base.frozen import frozen_array
from jiggle.rig.character.character import Character
from jiggle.rig.muscle.conform import ConformReport, conform
from jiggle.rig.muscle.ellipsoid import Ellipsoid, fit_ellipsoid, surface_moments
from jiggle.rig.muscle.fit_quality import assess, local_radius, thresholds

UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FitOptions:
    """How to fit.

    iterations, lam : normal smoothing for the segmentation (paper: 25 iterations, lambda 1).
    subdivisions : icosphere level of each muscle's mesh (3: 642 vertices).
    exclude : joint names or segment labels left out of the segmentation.
    overrides : {segment label: vertex indices} forced into a region.
    volume : rule keeping the muscles' volume ("exact", "sqrt", "thesis", "none").
    joint_map : a joint map preset name or TOML path naming the template's roles; None: automatic.
    reach : skin hits farther than this many ellipsoid radii along a conforming ray are ignored.
    smoothing : passes smoothing each conformed muscle's displacement over its mesh (rig.muscle.conform).
    min_vertices : a coarser skin is subdivided (same surface) for fitting, see `_dense_skin`.
    strict : raise InputError when a muscle is refused by the fit quality check (rig.muscle.fit_quality)
        instead of dropping it with a JiggleWarning.
    """

    iterations: int = 25
    lam: float = 1.0
    subdivisions: int = 3
    exclude: tuple[str, ...] = ()
    overrides: dict | None = None
    volume: str = "exact"
    joint_map: str | None = None
    reach: float = 3.0
    smoothing: int = 8
    min_vertices: int = 8000
    strict: bool = False

    def __post_init__(self):
        if not (isinstance(self.iterations, int) and 0 <= self.iterations <= 1000):
            raise InputError(f"expected an integer in [0, 1000], got {self.iterations!r}", field="iterations")
        if not 0.0 <= self.lam <= 1.0:
            raise InputError(f"expected a number in [0, 1], got {self.lam!r}", field="lambda")
        if not (isinstance(self.subdivisions, int) and 1 <= self.subdivisions <= 5):
            raise InputError(f"expected an integer in [1, 5], got {self.subdivisions!r}", field="subdivisions")
        if not self.reach > 0:
            raise InputError(f"expected a positive number, got {self.reach!r}", field="reach")


@dataclass(frozen=True, eq=False)
class FittedMuscle:
    """One fitted muscle at bind (world metres).

    name, kind ("muscle" | "fat"), group (the pair's bone label, or the multi-belly's name), side
        ("upper" | "lower" | "single").
    bone : joint index a, the start joint of the template bone (its frame carries the muscle).
    bone_label : "parent>child" joint names of the template bone.
    ellipsoid : the best-fit ellipsoid.
    vertices, faces : (n, 3) conformed mesh, (f, 3) int32.
    joints : (4,) int32 joints carrying origin, origin hinge, insertion hinge, insertion.
    points : (4, 3) those points at bind.
    region : (k,) int32 skin triangles fitted.
    plane : (point (3,), normal (3,)) of the pair's partition plane on this muscle's side, or None.
    report : the conforming rays' hits and misses.
    spec : the template entry it came from.
    radius : metres, the local body radius about its template bone (rig.muscle.fit_quality.local_radius
        of its region), the scale its fit errors are judged against.
    """

    name: str
    kind: str
    group: str
    side: str
    bone: int
    bone_label: str
    ellipsoid: Ellipsoid
    vertices: np.ndarray
    faces: np.ndarray
    joints: np.ndarray
    points: np.ndarray
    region: np.ndarray
    plane: tuple | None
    report: ConformReport
    spec: object
    radius: float

    def __post_init__(self):
        for k in ("vertices", "points"):
            object.__setattr__(self, k, frozen_array(getattr(self, k)))
        for k in ("faces", "joints", "region"):
            object.__setattr__(self, k, frozen_array(getattr(self, k), np.int32))

    @property
    def tendons(self) -> np.ndarray:
        """(2, 3, 3) metres: origin -> hinge -> belly start, belly end -> hinge -> insertion."""
        ends = self.ellipsoid.ends
        p = self.points
        return np.stack([[p[0], p[1], ends[0]], [ends[1], p[2], p[3]]])


@dataclass(frozen=True, eq=False)
class Musculature:
    """A character's fitted muscles.

    character, template, roles ({role: joint index}), segmentation (rig.muscle.segmentation.Segmentation),
    front (3,) the character's front, skin (vertices (V', 3), faces (F', 3), region (V',)) the skin fitted
    to (the character's, subdivided when coarse; FittedMuscle.region indexes its faces), muscles (tuple
    of FittedMuscle), rig (rig.muscle.model.MuscleRig,
    same order), skipped ((name, reason), ...) template muscles that could not be fitted or were refused,
    timings {stage: seconds}, plan (rig.motion.body_plan.BodyPlan) the skeleton's body plan,
    quality (tuple of rig.muscle.fit_quality.MuscleQuality, same order as muscles) how well each fits,
    refused (tuple of MuscleQuality) the muscles the quality check dropped from the rig (also in skipped),
    why : one sentence saying why this template was used (the body plan's, the generic one and why, or the
    user's), parts (tuple of rig.muscle.generic.Part) how the generic template judged each body part (empty
    for the other templates).
    """

    character: Character
    template: object
    roles: dict
    segmentation: object
    front: np.ndarray
    skin: tuple
    muscles: tuple
    rig: object
    skipped: tuple = ()
    timings: dict = field(default_factory=dict)
    plan: object = None
    quality: tuple = ()
    refused: tuple = ()
    why: str = ""
    parts: tuple = ()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.muscles)

    def muscle(self, name: str) -> FittedMuscle:
        for m in self.muscles:
            if m.name == name:
                return m
        raise KeyError(f"no muscle named {name!r}; muscles: {', '.join(self.names)}")

    @property
    def warned(self) -> tuple:
        """MuscleQuality of the muscles kept with a warning (worse than ok, not refused)."""
        return tuple(q for q in self.quality if q.status != "ok")


@dataclass(frozen=True)
class _Bone:
    """A template bone on this character: joints, straight line, frame and region triangles."""

    label: str
    parent: int
    child: int
    start: np.ndarray
    end: np.ndarray
    frame: np.ndarray  # (3, 3) rows e_along, e_front, e_side
    faces: np.ndarray  # skin triangles in its region

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    def point(self, position, default: np.ndarray) -> np.ndarray:
        if position is None:
            return default
        xyz = np.asarray(position.xyz, dtype=np.float64)
        if position.type == "absolute":
            return xyz
        return self.start + self.length * (xyz @ self.frame)


@dataclass(frozen=True, eq=False)
class _FitSkin:
    """The skin the muscles are fitted to: the character's, subdivided when coarse (_dense_skin).

    vertices (V', 3) metres, faces (F', 3) int32, region (V',) the segmentation's region of each vertex,
    face_region (F',) each triangle's region, centroids (F', 3), normals (F', 3) area-weighted (twice
    the triangle's area long), mesh the trimesh of vertices and faces (for rays and inside tests),
    size metres, its largest extent along an axis.
    """

    vertices: np.ndarray
    faces: np.ndarray
    region: np.ndarray
    face_region: np.ndarray
    centroids: np.ndarray
    normals: np.ndarray
    mesh: object
    size: float


def _fit_skin(character: Character, seg, min_vertices: int) -> _FitSkin:
    """The skin to fit to: `character`'s, subdivided to `min_vertices` (_dense_skin), with its regions from
    the segmentation `seg` and the per-triangle data the fit uses."""
    import trimesh
    V, F, region = _dense_skin(character.vertices, character.faces, seg, min_vertices)
    face_region = _face_regions(region, F)
    centroids = V[F].mean(axis=1)
    normals = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # area-weighted
    mesh = trimesh.Trimesh(V, F, process=False)
    size = max(float(np.ptp(V, axis=0).max()), 1e-9)
    return _FitSkin(V, F, region, face_region, centroids, normals, mesh, size)


def bone_frame(start: np.ndarray, end: np.ndarray, front: np.ndarray, fallback: np.ndarray | None = None
               ) -> np.ndarray:
    """(3, 3) rows e_along, e_front, e_side of a bone at bind: e_front is `front` (the character's front,
    or up for a template pair whose reference is "up") made perpendicular to the bone, or `fallback`
    (default world +Z) when the bone points along it; e_side = e_along x e_front."""
    along = end - start
    along = along / np.linalg.norm(along)
    f = front - (front @ along) * along
    if np.linalg.norm(f) < 0.2:
        z = np.array([0.0, 0.0, 1.0]) if fallback is None else np.asarray(fallback, float)
        f = z - (z @ along) * along
    f = f / np.linalg.norm(f)
    return np.stack([along, f, np.cross(along, f)])


def _chain(parents: np.ndarray, top: int, bottom: int) -> list[int] | None:
    """Joints from `top` down to `bottom` (both included), or None when bottom is not below top."""
    path = [bottom]
    while path[-1] != top:
        p = int(parents[path[-1]])
        if p < 0:
            return None
        path.append(p)
    return path[::-1]


def _collapsed_into(parents: np.ndarray, pos: np.ndarray, j: int) -> int:
    """The joint that starts `j`'s bone segments: j itself, or the ancestor it sits on through
    zero-length links (the tolerance of rig.muscle.segmentation.bone_segments, 1e-6 of the skeleton's size)."""
    eps = 1e-6 * max(float(np.ptp(pos, axis=0).max()), 1e-9)
    while parents[j] >= 0 and np.linalg.norm(pos[j] - pos[parents[j]]) <= eps:
        j = int(parents[j])
    return j


@dataclass(frozen=True, eq=False)
class TemplateChoice:
    """Which template a character gets, and why (choose_template).

    template : the Template to fit, or None for the generic one (rig.muscle.generic).
    plan : the skeleton's body plan (rig.motion.body_plan.BodyPlan); why : one sentence saying why.
    roles : {role: joint index} in the character's joints ({} for the generic template); front : (3,) its
        front, or None for the generic template. body, order : rig.character.body_skeleton.body_skeleton's.
    """

    template: object
    plan: object
    roles: dict
    front: np.ndarray | None
    why: str
    body: object
    order: np.ndarray


def choose_template(character: Character, template="auto", joint_map: str | None = None,
                    roles: dict | None = None, front: np.ndarray | None = None) -> TemplateChoice:
    """The template `character` gets: `template` when it is a Template, a built-in name or a path (its roles must
    fit: InputError otherwise), the generic one for "generic"; for "auto" or None the built-in template of the
    skeleton's body plan, or the generic one when no plan fits or the plan's roles (found without a joint map)
    do not fit the joints. The roles are read off the body's skeleton (rig.character.body_skeleton: helper bones
    such as IK and pole targets set aside, IK-placed feet hung under their legs). `front` given: the character's
    front is not read from its roles."""
    from jiggle.rig.character.body_skeleton import body_skeleton
    from jiggle.rig.motion.body_plan import detect_body_plan
    from jiggle.rig.motion.role_map import facing, resolve_roles
    from jiggle.rig.muscle.generic import GENERIC
    from jiggle.rig.muscle.template import Template, check_labels, load_template
    body, order = body_skeleton(character)
    plan = detect_body_plan(body)

    def generic(why: str) -> TemplateChoice:
        return TemplateChoice(None, plan, {}, None, why, body, order)
    if isinstance(template, str) and template == GENERIC:
        return generic("asked for (--template generic)")
    auto = not isinstance(template, Template) and template in (None, "auto")
    if auto:
        if plan.template is None:
            return generic(f"no built-in body plan fits ({plan.reason})")
        template, why = plan.template, f"the {plan.kind}'s built-in template ({plan.reason})"
    else:
        why = "asked for (--template)"
    tpl = template if isinstance(template, Template) else load_template(template)
    try:
        if roles is None:
            roles = {r: int(order[j]) for r, j in resolve_roles(body, joint_map).items()}
        else:
            roles = dict(roles)
        if "spine" not in roles and "hips" in roles and "chest" in roles:
            # no joint between the pelvis and the chest (a game rig's two-bone trunk): the trunk's bone starts
            # at the hips, as on CMU skeletons, whose spine joint sits at the hips' place
            roles["spine"] = roles["hips"]
        tpl = _without_optional(tpl, roles)
        check_labels(tpl, roles, character.joint_names, plan)
        front = facing(character.bind_positions, roles)[0] if front is None else front
    except InputError as e:
        if not auto or joint_map is not None:
            raise       # the user named the template or the joint map: their choice fails, say so
        # the skeleton looked like a biped or quadruped, but its joints do not play the roles: tissue anyway
        why = f"the {tpl.name} template's roles do not fit ({e.message})"
        warnings.warn(f"placing tissue with the generic template: {why}", JiggleWarning, stacklevel=3)
        return generic(why)
    return TemplateChoice(tpl, plan, roles, front, why, body, order)


def fit_musculature(character: Character, template="auto", options: FitOptions = FitOptions(), *,
                    roles: dict | None = None, front: np.ndarray | None = None) -> Musculature:
    """Fit `template` (a Template, a built-in name or a path; "generic": tissue on the skin's segmentation
    by bone, rig.muscle.generic; "auto" or None: the built-in one of the skeleton's body plan,
    rig.motion.body_plan, and the generic one when no plan fits or the plan's roles cannot be read off the
    joints without a joint map) to `character`.

    roles : {role: joint index}; default: rig.motion.role_map.resolve_roles of the body's skeleton (rig.character.body_skeleton: helper bones set aside), options.joint_map.
    front : (3,) the character's front; default: from the legs (rig.motion.role_map.facing).

    Template muscles whose region is empty or too small are skipped with a JiggleWarning (listed in
    `Musculature.skipped`); a template label the character's skeleton cannot map raises InputError
    listing the labels it knows.

    Every fitted muscle is then judged (rig.muscle.fit_quality: loft error as a share of the local body
    radius, share of the loft inside the skin; `Musculature.quality`): a poor fit is kept with a
    JiggleWarning naming the muscle and why; a refused one (mostly outside the body, or a loft error
    over RMS_REFUSE) is dropped from the rig and listed in `skipped` and `refused`, or raises
    InputError when `options.strict`. Dropping a muscle leaves the others' loft fits as they were.
    """
    from jiggle.rig.muscle.segmentation import segment_skin

    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    choice = choose_template(character, template, options.joint_map, roles, front)
    shape = _skin_skeleton(character, choice)
    front = _front(character, choice, front)
    seg = segment_skin(shape, iterations=options.iterations, lam=options.lam, exclude=options.exclude,
                       overrides=options.overrides)
    timings["segmentation"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    skin = _fit_skin(character, seg, options.min_vertices)
    skipped: list[tuple[str, str]] = []
    if choice.template is None:
        tpl, parts, fitted = _fit_generic(character, seg, skin, front, choice.roles, options)
    else:
        tpl, parts = choice.template, ()
        fitted = _fit_template(tpl, character, shape, seg, skin, choice.roles, front, options, skipped)
    timings["fit"] = time.perf_counter() - t1
    if not fitted:
        raise InputError("no muscle of the template could be fitted to this character", character.source or None)

    t2 = time.perf_counter()
    rig = _build_rig(character, fitted, options.volume)
    timings["muscle model"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    fitted, rig, quality, refused = _judge_fits(character, fitted, rig, skin, options, skipped)
    timings["quality"] = time.perf_counter() - t3
    timings["total"] = time.perf_counter() - t0
    return Musculature(character=character, template=tpl, roles=choice.roles, segmentation=seg, front=front,
                       skin=(skin.vertices, skin.faces, skin.region), muscles=tuple(fitted), rig=rig,
                       skipped=tuple(skipped), timings=timings, plan=choice.plan, quality=tuple(quality),
                       refused=tuple(refused), why=choice.why, parts=parts)


def _skin_skeleton(character: Character, choice: TemplateChoice) -> Character:
    """`character` with the parents of the body's skeleton (choice.body: helper bones set aside), the tree
    the skin is segmented on; `character` itself when the body is its skeleton."""
    from jiggle.rig.character.body_skeleton import original_parents
    if choice.body is character.skeleton:
        return character
    return replace(character, parents=original_parents(choice.body, choice.order))


def _front(character: Character, choice: TemplateChoice, front: np.ndarray | None) -> np.ndarray:
    """(3,) the character's front: `front` made unit when given, else the generic template's or the one
    read off the roles (choice.front)."""
    from jiggle.rig.muscle.generic import generic_front
    if front is not None:
        return np.asarray(front, float) / np.linalg.norm(front)
    if choice.template is None:
        return generic_front(character)
    return choice.front


def _skip(skipped: list, name: str, reason: str) -> None:
    """Leave the muscle `name` out: list (name, reason) in `skipped` and warn. Called from the fit's steps,
    one call below fit_musculature, so that the warning points at fit_musculature's caller."""
    skipped.append((name, reason))
    warnings.warn(f"muscle {name!r} skipped: {reason}", JiggleWarning, stacklevel=4)


def _fit_generic(character: Character, seg, skin: _FitSkin, front: np.ndarray, roles: dict, options: FitOptions
                 ) -> tuple[object, tuple, list[FittedMuscle]]:
    """The generic template (rig.muscle.generic) made from the skin's segmentation by bone, the parts it
    judged, and its muscles fitted, one on each part's whole region (its chain of bone segments)."""
    from jiggle.rig.muscle.generic import generic_parts, generic_template
    segs = seg.segments
    parts = tuple(generic_parts(skin.vertices, skin.faces, skin.face_region, segs, character.normals, seg.region))
    tpl, where = generic_template(parts)
    fitted = []
    for pair in tpl.pairs:
        m = pair.muscles[0]
        p = parts[where[m.name]]
        start, end = segs.start[p.segments[0]], segs.end[p.segments[-1]]
        bone = _Bone(label=p.label, parent=p.joint, child=p.child, start=start, end=end,
                     frame=bone_frame(start, end, front),
                     faces=np.flatnonzero(np.isin(skin.face_region, p.segments)))
        fitted.append(_fit_one(m.name, m, pair, bone, bone.faces, None, skin, roles, options,
                               group=p.label, belly=False))
    return tpl, parts, fitted


def _fit_template(tpl, character: Character, shape: Character, seg, skin: _FitSkin, roles: dict,
                  front: np.ndarray, options: FitOptions, skipped: list) -> list[FittedMuscle]:
    """Every muscle of `tpl` fitted to its sub-region of its pair's bone region (each belly of a
    multi-belly muscle to its strip); a muscle whose bone has zero length or whose region is empty or
    under three triangles is skipped (_skip)."""
    fitted = []
    for pair in tpl.pairs:
        label, bone = _template_bone(pair, tpl, character, shape, seg, skin, roles, front)
        if bone is None:
            for m in pair.muscles:
                _skip(skipped, m.name, f"its bone {label} has zero length")
            continue
        for m in pair.muscles:
            plane = _plane(bone, pair, m)
            pieces = _sub_region(bone, m, plane, skin.centroids)
            if len(pieces) == 0:
                _skip(skipped, m.name, f"its region on {label} is empty")
                continue
            strips = _strips(skin.vertices, skin.faces, pieces, bone, m.count) if m.kind == "multi_belly" else [pieces]
            for k, faces in enumerate(strips):
                name = m.name if len(strips) == 1 else f"{m.name}_{k + 1}"
                if len(faces) < 3:
                    _skip(skipped, name, f"its region on {label} has only {len(faces)} triangles")
                    continue
                fitted.append(_fit_one(name, m, pair, bone, faces, plane, skin, roles, options,
                                       group=m.name if len(strips) > 1 else label, belly=len(strips) > 1))
    return fitted


def _template_bone(pair, tpl, character: Character, shape: Character, seg, skin: _FitSkin, roles: dict,
                   front: np.ndarray) -> tuple[str, _Bone | None]:
    """The "parent>child" joint names of `pair`'s bone, and the bone on this character (None when it has
    zero length): the straight line between its joints, its frame, and the skin triangles of the bone
    segments along the chain of joints between them. InputError when the child is not below the parent."""
    names, pos = character.joint_names, character.bind_positions
    p_joint, c_joint = roles[pair.parent], roles[pair.child]
    label = f"{names[p_joint]}>{names[c_joint]}"
    chain = _chain(shape.parents, p_joint, c_joint)
    if chain is None:
        raise InputError(f"the template bone {pair.parent}>{pair.child} does not follow the skeleton: "
                         f"{names[c_joint]!r} is not below {names[p_joint]!r}", tpl.source or None,
                         field=f"bone {pair.parent}>{pair.child}")
    start, end = pos[p_joint], pos[c_joint]
    if np.linalg.norm(end - start) < 1e-4 * skin.size:
        return label, None
    segs = seg.segments
    # a chain joint at its parent's place (CMU's LowerBack on Hips) starts no segment of its own:
    # rig.muscle.segmentation collapsed it, and its bone is the segment from the joint it collapsed into
    starts = chain[:-1] + [_collapsed_into(shape.parents, pos, j) for j in chain[:-1]]
    on_chain = np.isin(segs.parent, starts) & np.isin(segs.child, chain[1:])
    return label, _Bone(label=label, parent=p_joint, child=c_joint, start=start, end=end,
                        frame=bone_frame(start, end, UP, front) if pair.reference == "up" else
                        bone_frame(start, end, front),
                        faces=np.nonzero(np.isin(skin.face_region, np.nonzero(on_chain)[0]))[0])


def _build_rig(character: Character, fitted: list[FittedMuscle], volume: str):
    """The muscle rig (rig.muscle.model.MuscleRig) of the fitted muscles, in their order."""
    from jiggle.rig.muscle.model import MuscleSpec, build_muscle_rig
    specs = [MuscleSpec(name=f.name, kind=f.kind, group=f.group, bone=f.bone,
                        bones=f.joints, points=f.points, ends=f.ellipsoid.ends, up=f.ellipsoid.axes[1],
                        surface=f.vertices, rim_scale=f.spec.rim_scale, bulge_scale=f.spec.bulge_scale,
                        main_scale=f.spec.main_scale, bulge_position=f.spec.bulge_position, tone=f.spec.tone,
                        middle_offset=np.zeros(3))
             for f in fitted]
    return build_muscle_rig(specs, character.bind_world, volume=volume)


def _judge_fits(character: Character, fitted: list[FittedMuscle], rig, skin: _FitSkin, options: FitOptions,
                skipped: list) -> tuple[list[FittedMuscle], object, list, list]:
    """The fit quality check (rig.muscle.fit_quality.assess) of every fitted muscle: a poor fit is kept with
    a warning, a refused one is skipped (_skip) and dropped from the rig, which is rebuilt without it
    (InputError instead when options.strict, or when every muscle is refused). Returns the kept muscles,
    their rig, their MuscleQuality and the refused muscles' MuscleQuality."""
    quality = assess([f.name for f in fitted], rig.surface(rig.rest_cvs), rig.fit_rms, rig.fit_max,
                     [f.radius for f in fitted], skin.mesh)
    refused = [q for q in quality if q.status == "refused"]
    if refused and options.strict:
        raise InputError("the fit refuses " + "; ".join(f"muscle {q.name!r}: {', '.join(q.reasons)}" for q in refused)
                         + f" (thresholds: {thresholds()})", character.source or None, field="fit quality")
    for q in quality:
        if q.status == "warn":
            warnings.warn(f"muscle {q.name!r} fits poorly: {'; '.join(q.reasons)}", JiggleWarning, stacklevel=3)
        elif q.status == "refused":
            _skip(skipped, q.name, "refused by the fit quality check: " + "; ".join(q.reasons))
    if refused:
        keep = [i for i, q in enumerate(quality) if q.status != "refused"]
        if not keep:
            raise InputError("no muscle of the template fits this character: "
                             + "; ".join(f"{q.name}: {', '.join(q.reasons)}" for q in refused), character.source or None)
        # each muscle's loft is fitted on its own, so the kept ones are rebuilt unchanged
        fitted, quality = [fitted[i] for i in keep], [quality[i] for i in keep]
        rig = _build_rig(character, fitted, options.volume)
    return fitted, rig, quality, refused


AXIS_SAMPLES = 21  # points along a fitted ellipsoid's major axis tested against the skin
AXIS_BISECTIONS = 10  # steps locating where the axis leaves the skin (1/1000 of a sample step)


def _axis_inside(e: Ellipsoid, skin, bone: _Bone) -> Ellipsoid:
    """`e` with its major axis inside the skin: the axis of a patch's ellipsoid runs straight along the
    patch, and where the body curves under it (a dog's upper foreleg along its barrel) its ends leave
    the body, and the conformed muscle with them. A centre outside the skin moves toward the bone
    until it is inside; then the axis is cut to the run of samples inside around the centre (the other
    radii no longer than the major one). An ellipsoid whose axis is inside is returned as it is."""
    from jiggle.rig.muscle.fit_quality import inside_skin
    t = np.linspace(-1.0, 1.0, AXIS_SAMPLES)
    mid = AXIS_SAMPLES // 2
    centre = np.array(e.centre)
    inside = inside_skin(skin, centre + (t * e.radii[0])[:, None] * e.axes[0])
    if inside.all():
        return e
    if not inside[mid]:
        seg = bone.end - bone.start
        u = np.clip((centre - bone.start) @ seg / max(seg @ seg, 1e-18), 0.0, 1.0)
        target = bone.start + u * seg
        for k in range(1, 11):
            moved = centre + 0.1 * k * (target - centre)
            inside = inside_skin(skin, moved + (t * e.radii[0])[:, None] * e.axes[0])
            if inside[mid]:
                centre = moved
                break
        else:
            return e  # no inside to be found: the quality check names the muscle
    lo, hi = mid, mid
    while lo > 0 and inside[lo - 1]:
        lo -= 1
    while hi < AXIS_SAMPLES - 1 and inside[hi + 1]:
        hi += 1

    def crossing(a: float, b: float) -> float:
        """Where the axis leaves the skin between t = a (inside) and b (outside), by bisection (so that
        mirrored muscles are cut alike, not at the nearest sample)."""
        for _ in range(AXIS_BISECTIONS):
            m = 0.5 * (a + b)
            if inside_skin(skin, (centre + m * e.radii[0] * e.axes[0])[None])[0]:
                a = m
            else:
                b = m
        return a

    t0 = crossing(t[lo], t[lo - 1]) if lo > 0 else -1.0
    t1 = crossing(t[hi], t[hi + 1]) if hi < AXIS_SAMPLES - 1 else 1.0
    r0 = max(0.5 * (t1 - t0), 1.0 / (AXIS_SAMPLES - 1)) * e.radii[0]
    centre = centre + 0.5 * (t0 + t1) * e.radii[0] * e.axes[0]
    return Ellipsoid(centre=centre, axes=e.axes, radii=np.minimum(e.radii, r0))


def _without_optional(tpl, roles: dict):
    """`tpl` without the pairs that need a role the skeleton does not have when that role is optional
    (rig.muscle.template.OPTIONAL_ROLES: a collar bone, a toe, a tail), each left out with a JiggleWarning."""
    from jiggle.rig.muscle.template import OPTIONAL_ROLES
    keep = []
    for pair in tpl.pairs:
        labels = {pair.parent, pair.child} | {a for m in pair.muscles for a in pair.riding(m)}
        gone = sorted(r for r in labels if r not in roles and r in OPTIONAL_ROLES)
        if gone:
            warnings.warn(f"muscles {', '.join(m.name for m in pair.muscles)} left out: the skeleton has no "
                          f"{' or '.join(gone)}", JiggleWarning, stacklevel=3)
        else:
            keep.append(pair)
    return replace(tpl, pairs=tuple(keep)) if len(keep) < len(tpl.pairs) else tpl


def _dense_skin(vertices: np.ndarray, faces: np.ndarray, seg, min_vertices: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The skin to fit to: the character's, split into four triangles per triangle (midpoints, same
    surface) until it has `min_vertices`, so that a coarse mesh (RiggedFigure: 370 vertices) still
    gives every sub-region, strip and pair half enough triangles to fit. The character's own vertices
    keep their regions (overrides included); a new midpoint vertex is assigned by the same normal test
    with its endpoints' low-frequency normals averaged. Returns vertices, faces, region per vertex."""
    from jiggle.rig.muscle.segmentation import assign
    V, F = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    region, low = np.asarray(seg.region), np.asarray(seg.low_normals)
    while len(V) < min_vertices and len(F):
        edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = len(V) + inverse.reshape(3, -1).T  # (F, 3) midpoints of edges 01, 12, 20
        new_v = 0.5 * (V[unique[:, 0]] + V[unique[:, 1]])
        n = low[unique[:, 0]] + low[unique[:, 1]]
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        new_r, _ = assign(new_v, n, seg.segments)
        a, b, c = F[:, 0], F[:, 1], F[:, 2]
        ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
        F = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                            np.stack([ab, bc, ca], 1)])
        V, region, low = np.vstack([V, new_v]), np.concatenate([region, new_r]), np.vstack([low, n])
    return V, F.astype(np.int32), region


def _face_regions(region: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) the region of the majority of each triangle's corners (the first corner's on a three-way tie)."""
    r = region[faces]
    out = r[:, 0].copy()
    two = r[:, 1] == r[:, 2]
    out[two] = r[two, 1]
    return out


def _sub_region(bone: _Bone, m, plane, centroids: np.ndarray) -> np.ndarray:
    """The bone region's triangles within the muscle's span along the bone, sector about it and side of
    the pair's partition plane."""
    faces = bone.faces
    c = centroids[faces] - bone.start
    t = (c @ bone.frame[0]) / bone.length
    keep = (t >= m.span[0]) & (t <= m.span[1])
    if m.sector is not None:
        ang = np.degrees(np.arctan2(c @ bone.frame[2], c @ bone.frame[1]))
        keep &= (ang - m.sector[0]) % 360.0 <= m.sector[1] - m.sector[0]
    if plane is not None:
        keep &= (centroids[faces] - plane[0]) @ plane[1] >= 0
    return faces[keep]


def _plane(bone: _Bone, pair, m) -> tuple[np.ndarray, np.ndarray] | None:
    """The pair's partition plane through the bone's centre, normal turned toward this muscle's side:
    theta = cos(angle) e_front + sin(angle) e_side; the "upper" muscle lies on theta's side."""
    if m.type == "single":
        return None
    a = np.radians(pair.partition_deg)
    theta = np.cos(a) * bone.frame[1] + np.sin(a) * bone.frame[2]
    return 0.5 * (bone.start + bone.end), theta if m.type == "upper" else -theta


def _strips(V: np.ndarray, F: np.ndarray, faces: np.ndarray, bone: _Bone, count: int) -> list[np.ndarray]:
    """`faces` cut into `count` strips of equal area across the bone, along the region's principal
    direction most perpendicular to it."""
    _, _, cov = surface_moments(V, F[faces])
    w, v = np.linalg.eigh(cov)
    spread = np.clip(w, 0.0, None) * (1.0 - (v.T @ bone.frame[0]) ** 2)  # variance across the bone
    across = v[:, np.argmax(spread)]
    tri = V[F[faces]]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    s = tri.mean(axis=1) @ across
    order = np.argsort(s)
    cum = np.cumsum(area[order]) / max(area.sum(), 1e-30)
    k = np.minimum((cum * count).astype(int), count - 1)
    return [np.sort(faces[order[k == i]]) for i in range(count)]


def _fit_one(name, m, pair, bone: _Bone, faces, plane, skin: _FitSkin, roles, options: FitOptions,
             group: str, belly: bool) -> FittedMuscle:
    """The muscle `name` of template entry `m` fitted to the triangles `faces` of `skin` (indices into
    skin.faces) on `bone`: ellipsoid, major axis kept inside the skin, conformed mesh, attachments."""
    V, F, normals = skin.vertices, skin.faces, skin.normals
    n = normals[faces].sum(axis=0)
    area2 = np.linalg.norm(normals[faces], axis=1).sum()
    # a patch of skin (pectoral, fat) has a clear outward side; a ring around a limb does not
    outward = n / np.linalg.norm(n) if np.linalg.norm(n) > 0.3 * area2 else (plane[1] if plane else None)
    thickness = max(m.thickness_min, m.depth if m.kind == "fat" else 0.0)
    e = fit_ellipsoid(V, F[faces], along=bone.frame[0], outward=outward, thickness_min=thickness)
    e = _axis_inside(e, skin.mesh, bone)
    pts, tri = e.mesh(options.subdivisions)
    allowed = np.zeros(len(F), bool)
    allowed[bone.faces] = True
    conformed, report = conform(e, pts, skin.mesh, nu=m.nu, plane=plane, reach=options.reach, allowed=allowed,
                                faces=tri, smoothing=options.smoothing)
    ends = e.ends

    def joint(att, default: int) -> int:
        return roles[att.joint] if att.joint is not None else default

    origin_default = ends[0] if belly else bone.start
    points = np.stack([bone.point(m.origin.position, origin_default),
                       bone.point(m.o_hinge.position, ends[0]),
                       bone.point(m.i_hinge.position, ends[1]),
                       bone.point(m.insertion.position, bone.end)])
    joints = np.array([joint(m.origin, bone.parent), joint(m.o_hinge, bone.parent),
                       joint(m.i_hinge, bone.parent), joint(m.insertion, bone.child)], dtype=np.int32)
    return FittedMuscle(name=name, kind="fat" if m.kind == "fat" else "muscle", group=group, side=m.type,
                        bone=bone.parent, bone_label=bone.label, ellipsoid=e, vertices=conformed, faces=tri,
                        joints=joints, points=points, region=faces, plane=plane, report=report,
                        spec=m, radius=local_radius(V, F[faces], bone.start, bone.end))
