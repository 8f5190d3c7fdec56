"""Morph a canonical character into a target from sparse marker positions (Simmons et al. 2002,
sections 3 and 4), inside out: joints, bones, muscles, then the skin.

    canonical character --fit_musculature--> muscles; --find_features--> feature vertices anchored to
        bones and muscles (the skin resampled to hold them); --body_zones--> geodesic zones;
        --find_markers--> the marker vertices
    target markers --> joint positions (joint markers), chains without markers distributed keeping
        their canonical shape, a similarity per remaining joint
    --> one affine map per bone segment: rotation and length from the placed joints, thickness from
        the body dimensions the markers measure (rig.anatomy.markers.WIDTHS), across the bone
    --> muscles: each section's CVs through the affine maps of the bones at the muscle's two ends,
        mixed linearly across the sections (so a muscle's cross-sections scale with the body
        dimensions at its ends, linearly in between)
    --> feature points: bone anchors through their bone's map, muscle anchors on the morphed lofts
    --> skin: zoned RBF interpolation of the feature displacements (rig.anatomy.rbf.interpolate)
    --> a Character: the morphed skin, the morphed skeleton (joint frames turned with their bones),
        the canonical's skin weights; `jiggle morph` writes it as a skinned glTF.

Joints (section 3.2). A joint marker locates its joint by keeping the canonical offset between marker
and joint, turned and scaled by the map of the bone segment nearest the marker (the marker's
component, as the paper anchors markers to the nearest component); the maps need the joints, so the
estimate runs twice (offsets as they are, then through the first pass's maps). A joint without a
marker that lies on the tree path from a located joint a to a located descendant b (the nearest,
preferring the next role of its chain) goes with the chain: the similarity (rotation, uniform scale)
taking canonical a->b onto target a->b, so the chain keeps its canonical shape and ends exactly at
b. A joint below every located joint (toes, fingers) follows its parent's bone similarity.

Bones (section 3.3). Segment s from joint p to joint c (or to its estimated end):
    A_s(x) = x_p' + R_s F_s^T diag(l, f, w) F_s (x - x_p)
with R_s the smallest rotation taking the canonical bone direction to the target's, l the length
ratio, F_s the bone frame (along, front, side; rig.muscle.segmentation.BoneSegments.frames) and f, w the
ratios of the body dimensions measured across that bone (1 where nothing is measured). A chain's last
bone takes direction and length from its tip marker (hand tip, toe, head top) when there is one.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from jiggle.rig.anatomy.markers import HUMAN, NEXT_ROLE, WIDTHS, MarkerSet, find_markers, role_axis
from jiggle.rig.base.errors import InputError
from jiggle.rig.character.normals import vertex_normals

TRUNK = ("hips", "spine", "chest", "neck", "head")


@dataclass(frozen=True)
class MorphOptions:
    """Options of a morph. Lengths as fractions of the canonical's height.

    template : musculoskeletal template for the canonical's muscles (rig.muscle.template).
    kernel : RBF kernel (rig.anatomy.rbf.KERNELS); scale : its scale s (soliton e^{-r/s}), fraction of height.
    band : blend band across zone boundaries, fraction of height.
    merge : centres closer than this (fraction of height) merge in the RBF.
    marker_features : also use the marker vertices as feature points, at the target's positions
        (the paper's option: exact markers, but a misplaced marker then dents the skin).
    features : rig.anatomy.features.FeatureOptions or None for the defaults.
    joint_map : roles of the canonical's joints (preset, TOML) or None to find them.
    """

    template: str = "human"
    kernel: str = "soliton"
    scale: float = 0.1
    band: float = 0.04
    merge: float = 1e-4
    marker_features: bool = False
    features: object = None
    joint_map: object = None


@dataclass(frozen=True, eq=False)
class Canonical:
    """A canonical character prepared for morphing (everything that does not depend on the target).

    character : the canonical on its resampled skin (feature vertices inserted).
    musculature : its fitted muscles (rig.muscle.fit.Musculature, fitted on the original skin).
    features : rig.anatomy.features.FeatureSet; zones : rig.anatomy.zones.Zones of the resampled skin;
    markers : rig.anatomy.markers.MarkerSet on the resampled skin; roles : {role: joint}; segments : BoneSegments;
    vertex_segment : (V,) bone segment of each resampled vertex; frames : (S, 3, 3) bone frames;
    height : metres; timings : {stage: seconds}.
    """

    character: object
    musculature: object
    features: object
    zones: object
    markers: MarkerSet
    roles: dict
    segments: object
    vertex_segment: np.ndarray
    frames: np.ndarray
    height: float
    source: str = ""
    timings: dict = field(default_factory=dict)


def prepare_canonical(character, options: MorphOptions = MorphOptions(), source: str = "") -> Canonical:
    """Fit, find feature and marker vertices, and zone a canonical character (see the module docstring)."""
    from jiggle.rig.anatomy.features import FeatureOptions, find_features
    from jiggle.rig.anatomy.resample import resample_character
    from jiggle.rig.anatomy.zones import body_zones
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature

    t = {}
    t0 = time.perf_counter()
    mus = fit_musculature(character, options.template, FitOptions(joint_map=options.joint_map))
    t["fit"] = time.perf_counter() - t0
    segments = mus.segmentation.segments
    t0 = time.perf_counter()
    fs = find_features(character, segments, mus.rig, options.features or FeatureOptions())
    t["features"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    resampled = resample_character(character, fs.skin)
    src = np.asarray(fs.skin.source)
    main = src[np.arange(len(src)), np.argmax(np.asarray(fs.skin.bary), axis=1)]
    vertex_segment = np.asarray(mus.segmentation.region)[main]
    H = character.height
    zones = body_zones(resampled.vertices, resampled.faces, vertex_segment, segments, character.parents,
                       character.joint_names, mus.roles, options.band * H)
    # markers on the original skin (its vertices keep their indices in the resampled one), so a
    # canonical's marker file does not depend on the feature options
    markers = find_markers(character.vertices, character.faces, mus.roles, character.bind_positions, segments, HUMAN)
    t["zones+markers"] = time.perf_counter() - t0
    return Canonical(resampled, mus, fs, zones, markers, dict(mus.roles), segments, vertex_segment,
                     segments.frames(mus.front), H, source, t)


# ---------------------------------------------------------------------------------- geometry
def min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking direction a (3,) to direction b (3,)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        axis = axis if np.linalg.norm(axis) > 1e-6 else np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def _similarity(a_c, b_c, a_t, b_t) -> np.ndarray:
    """(4, 4) rotation + uniform scale taking a_c -> a_t and b_c -> b_t."""
    d_c, d_t = b_c - a_c, b_t - a_t
    m = np.eye(4)
    lc = np.linalg.norm(d_c)
    if lc < 1e-9 or np.linalg.norm(d_t) < 1e-9:
        m[:3, 3] = a_t - a_c
        return m
    m[:3, :3] = np.linalg.norm(d_t) / lc * min_rotation(d_c, d_t)
    m[:3, 3] = a_t - m[:3, :3] @ a_c
    return m


def _apply(m: np.ndarray, x: np.ndarray) -> np.ndarray:
    return x @ m[:3, :3].T + m[:3, 3]


# ---------------------------------------------------------------------------------- components
@dataclass(frozen=True, eq=False)
class ComponentMorph:
    """The morphed components. joints (J, 3) target joint positions, metres; segment_maps (S, 4, 4)
    affine map of each bone segment (canonical -> target); rotations (J, 3, 3) how each joint's frame
    turns; widths {name: ratio} of the measured body dimensions; cvs (N, 3) morphed muscle CVs."""

    joints: np.ndarray
    segment_maps: np.ndarray
    rotations: np.ndarray
    widths: dict
    cvs: np.ndarray


def _children(parents) -> list[list[int]]:
    ch = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            ch[p].append(j)
    return ch


def _located_below(j, children, located, role_of) -> int | None:
    """The nearest located descendant of j (breadth first), preferring the next role of j's chain."""
    level = list(children[j])
    while level:
        hits = [k for k in level if k in located]
        if hits:
            trunk = [k for k in hits if role_of.get(k) in TRUNK]
            return (trunk or hits)[0]
        level = [c for k in level for c in children[k]]
    return None


def place_joints(P: np.ndarray, parents, located: dict, role_of: dict) -> tuple[np.ndarray, np.ndarray]:
    """(x (J, 3) target joint positions, sims (J, 4, 4) the similarity each joint was placed by).

    P : (J, 3) canonical joint positions; located : {joint: target position}."""
    J = len(P)
    children = _children(parents)
    x, sims = np.zeros((J, 3)), np.tile(np.eye(4), (J, 1, 1))
    shift = np.mean([located[j] - P[j] for j in located], axis=0) if located else np.zeros(3)
    anchor = {}  # joint -> the located ancestor its chain starts from
    for j in range(J):  # parents first
        p = int(parents[j])
        if j in located:
            x[j] = located[j]
            anchor[j] = j
            if p >= 0:
                sims[j] = _similarity(P[p], P[j], x[p], x[j])
            continue
        if p < 0:
            x[j] = P[j] + shift
            sims[j][:3, 3] = shift
            anchor[j] = j
            continue
        a = anchor[p]
        b = _located_below(j, children, located, role_of)
        if b is not None:
            sims[j] = _similarity(P[a], P[b], x[a], located[b])
            anchor[j] = a
        else:
            sims[j] = sims[p].copy()
            sims[j][:3, 3] = x[p] - sims[p][:3, :3] @ P[p]   # keep turning and scaling from the parent
            anchor[j] = j
        x[j] = _apply(sims[j], P[j])
    return x, sims


def segment_maps(P, x, sims, segments, frames, scales, tips=None) -> np.ndarray:
    """(S, 4, 4) affine map of each bone segment from canonical joints P (J, 3), target joints x (J, 3),
    the joints' similarities (J, 4, 4), bone frames (S, 3, 3) and (front, side) thickness ratios
    `scales` (S, 2). A segment ending at "end" points at its tip marker, `tips` {segment: (canonical
    (3,), target (3,))}, when it has one, else turns with its joint's similarity."""
    S = len(segments.labels)
    out = np.tile(np.eye(4), (S, 1, 1))
    for s in range(S):
        p, c = int(segments.parent[s]), int(segments.child[s])
        d_c = (P[c] if c >= 0 else segments.end[s]) - P[p]
        tip = (tips or {}).get(s)
        if c >= 0:
            d_t = x[c] - x[p]
        elif tip is not None and min(np.linalg.norm(tip[0] - P[p]), np.linalg.norm(tip[1] - x[p])) > 1e-6:
            d_c, d_t = tip[0] - P[p], tip[1] - x[p]
        else:
            d_t = sims[p][:3, :3] @ d_c
        length = np.linalg.norm(d_c)
        if length < 1e-9:
            R, l_ratio = sims[p][:3, :3] / max(np.cbrt(abs(np.linalg.det(sims[p][:3, :3]))), 1e-12), 1.0
        else:
            R, l_ratio = min_rotation(d_c, d_t), np.linalg.norm(d_t) / length
        F = frames[s]
        L = R @ F.T @ np.diag([l_ratio, scales[s, 0], scales[s, 1]]) @ F
        out[s][:3, :3] = L
        out[s][:3, 3] = x[p] - L @ P[p]
    return out


def _segment_of_role(role: str, roles: dict, P: np.ndarray, segments) -> int | None:
    """The bone segment along `role`'s axis (starting at its joint, best aligned with the axis)."""
    j = roles.get(role)
    if j is None:
        return None
    own = np.nonzero(np.asarray(segments.parent) == j)[0]
    if not len(own):
        return None
    a, b = role_axis(role, roles, P, segments)
    axis = (b - a) / max(np.linalg.norm(b - a), 1e-12)
    d = segments.end[own] - segments.start[own]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return int(own[np.argmax(d @ axis)])


def morph_components(canon: Canonical, target: dict) -> ComponentMorph:
    """Joints, bone maps and muscle CVs of the target from marker positions {name: (3,)} (section 3)."""
    ch, seg, roles = canon.character, canon.segments, canon.roles
    P = np.asarray(ch.bind_positions, np.float64)
    parents = np.asarray(ch.parents)
    names = canon.markers.names
    m_c = np.asarray(canon.markers.positions)
    m_t = np.stack([target[n] for n in names])
    specs = canon.markers.specs
    role_of = {j: r for r, j in roles.items()}
    S = len(seg.labels)

    # body dimensions -> (front, side) thickness ratios per segment
    scales = np.ones((S, 2))
    widths = {}
    idx = {n: i for i, n in enumerate(names)}
    for name, a, b, role, axis in WIDTHS:
        if a not in idx or b not in idx:
            continue
        s = _segment_of_role(role, roles, P, seg)
        dc = np.linalg.norm(m_c[idx[a]] - m_c[idx[b]])
        if s is None or dc < 1e-6:
            continue
        r = float(np.linalg.norm(m_t[idx[a]] - m_t[idx[b]]) / dc)
        widths[name] = r
        if axis in ("front", "both"):
            scales[s, 0] = r
        if axis in ("side", "both"):
            scales[s, 1] = r

    # the segment each marker rides (its nearest component among the bones)
    _, dist = seg.project(m_c)
    marker_seg = dist.argmin(axis=1)
    tips = {}  # a chain's last bone points at its tip marker
    for i, sp in enumerate(specs):
        if sp.direction in ("along", "ahead"):
            s = _segment_of_role(sp.role, roles, P, seg)
            if s is not None and seg.child[s] < 0:
                tips[s] = (m_c[i], m_t[i])

    maps = np.tile(np.eye(4), (S, 1, 1))
    for _ in range(2):  # offsets as they are, then turned and scaled by the first pass's bone maps
        located = {}
        for i, sp in enumerate(specs):
            if sp.locates is None:
                continue
            j = roles[sp.locates]
            L = maps[marker_seg[i]][:3, :3]
            located.setdefault(j, []).append(m_t[i] - L @ (m_c[i] - P[j]))
        located = {j: np.mean(v, axis=0) for j, v in located.items()}
        x, sims = place_joints(P, parents, located, role_of)
        maps = segment_maps(P, x, sims, seg, canon.frames, scales, tips)

    # each joint's frame turns with the bone it starts (its chain's next bone), else with its parent's
    rotations = np.tile(np.eye(3), (len(P), 1, 1))
    for j in range(len(P)):
        own = np.nonzero(np.asarray(seg.parent) == j)[0]
        if len(own):
            s = own[0]
            nxt = roles.get(NEXT_ROLE.get(role_of.get(j)))
            pick = [k for k in own if nxt is not None and seg.child[k] == nxt]
            s = pick[0] if pick else s
            rotations[j] = _rotation_part(maps[s][:3, :3])
        elif parents[j] >= 0:
            rotations[j] = rotations[parents[j]]

    cvs = morph_muscles(canon, maps)
    return ComponentMorph(x, maps, rotations, widths, cvs)


def _rotation_part(L: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(L)
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


def morph_muscles(canon: Canonical, maps: np.ndarray) -> np.ndarray:
    """(N, 3) morphed CVs: muscle section k goes through lerp(A_first, A_last, k / 4), A_first and
    A_last the maps of the bone segments nearest the muscle's first and last sections (section 3.4)."""
    rig = canon.musculature.rig
    X = np.asarray(rig.rest_cvs, np.float64).reshape(rig.M, 5, 8, 3)
    centres = X.mean(axis=2)                                          # (M, 5, 3)
    _, d_first = canon.segments.project(centres[:, 0])
    _, d_last = canon.segments.project(centres[:, -1])
    a, b = maps[d_first.argmin(axis=1)], maps[d_last.argmin(axis=1)]   # (M, 4, 4)
    alpha = np.linspace(0.0, 1.0, 5)[None, :, None, None]
    A = (1.0 - alpha) * a[:, None] + alpha * b[:, None]                # (M, 5, 4, 4)
    out = np.einsum("mkij,mkrj->mkri", A[..., :3, :3], X) + A[:, :, None, :3, 3]
    return out.reshape(-1, 3)


# ---------------------------------------------------------------------------------- the morph
@dataclass(frozen=True, eq=False)
class MorphResult:
    """character : the target (rig.character.character.Character); components : ComponentMorph;
    report : {marker_rms_m, marker_rms_fraction, marker_max_m, markers {name: error m}, flipped,
    degenerate, rbf {...}, boundary {...}, features {...}, seconds {...}} (JSON-able)."""

    character: object
    components: ComponentMorph
    report: dict


def morph(canon: Canonical, target: dict, options: MorphOptions = MorphOptions()) -> MorphResult:
    """The target character for marker positions `target` {name: (3,) metres} (all of the canonical's)."""
    from jiggle.rig.anatomy.rbf import RBFOptions, boundary_report, interpolate
    from jiggle.rig.character.character import bind_clip

    t = {}
    missing = [n for n in canon.markers.names if n not in target]
    if missing:
        raise InputError(f"missing markers: {', '.join(missing)}", field="markers")
    bad = [n for n in canon.markers.names if not np.isfinite(np.asarray(target[n], np.float64)).all()]
    if bad:
        raise InputError(f"markers {', '.join(bad)} hold NaN or inf", field="markers")
    ch, fs, H = canon.character, canon.features, canon.height
    t0 = time.perf_counter()
    comp = morph_components(canon, target)
    anchors = fs.anchors
    rest = np.asarray(anchors.rest, np.float64)
    moved = anchors.positions(np.asarray(ch.bind_world), comp.cvs)
    bone = np.asarray(anchors.kind) == 0
    seg_of = np.asarray(anchors.segment)
    moved[bone] = np.einsum("nij,nj->ni", comp.segment_maps[seg_of[bone], :3, :3], rest[bone]) \
        + comp.segment_maps[seg_of[bone], :3, 3]
    feat_vertex = np.asarray(fs.vertex, np.int64)
    if options.marker_features:
        mv = np.asarray(canon.markers.vertex)
        want = np.stack([target[n] for n in canon.markers.names])
        keep = ~np.isin(mv, feat_vertex)
        # a marker on a feature vertex pins that feature; the others join as features of their own
        at = np.searchsorted(feat_vertex, mv[~keep]) if np.all(np.diff(feat_vertex) > 0) else \
            np.array([int(np.nonzero(feat_vertex == v)[0][0]) for v in mv[~keep]], np.int64)
        moved[at] = want[~keep]
        rest = np.concatenate([rest, np.asarray(ch.vertices)[mv[keep]]])
        moved = np.concatenate([moved, want[keep]])
        feat_vertex = np.concatenate([feat_vertex, mv[keep]])
    t["components"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    zone_of = np.asarray(canon.zones.vertex_zone)[feat_vertex]
    rbf_opt = RBFOptions(kernel=options.kernel, scale=options.scale * H, merge=options.merge * H, support=0)
    skin, info = interpolate(np.asarray(ch.vertices), rest, moved, zone_of, canon.zones, rbf_opt,
                             feature_vertex=feat_vertex)
    t["skin rbf"] = time.perf_counter() - t0
    if not np.isfinite(skin).all():
        raise InputError("the morphed skin holds NaN or inf (the RBF system is singular?)", field="markers")

    t0 = time.perf_counter()
    bw = np.asarray(ch.bind_world, np.float64).copy()
    bw[:, :3, :3] = comp.rotations @ bw[:, :3, :3]
    bw[:, :3, 3] = comp.joints
    normals = vertex_normals(skin, ch.faces)
    skeleton = bind_clip(ch.joint_names, ch.parents, bw, name=f"{ch.name} morphed", source=ch.source)
    target_char = replace(ch, vertices=skin, normals=normals, bind_world=bw, bind_matrices=bw, skeleton=skeleton,
                          name=f"{ch.name} morphed" if ch.name else "morphed",
                          meta={**ch.meta, "morphed_from": canon.source or ch.source})
    report = _report(canon, comp, skin, target, info, boundary_report(
        np.asarray(ch.vertices), np.asarray(ch.faces), skin - np.asarray(ch.vertices), canon.zones))
    t["report"] = time.perf_counter() - t0
    report["seconds"] = {**{k: round(v, 3) for k, v in canon.timings.items()}, **{k: round(v, 3) for k, v in t.items()}}
    return MorphResult(target_char, comp, report)


def flipped_faces(canon: Canonical, comp: ComponentMorph, skin: np.ndarray) -> tuple[int, int]:
    """(flipped, degenerate) faces of the morphed skin: a face is flipped when its normal points
    against its canonical normal turned by its bone's rotation, degenerate when its area vanishes."""
    f = np.asarray(canon.character.faces, np.int64)
    v0 = np.asarray(canon.character.vertices)
    n0 = np.cross(v0[f[:, 1]] - v0[f[:, 0]], v0[f[:, 2]] - v0[f[:, 0]])
    n1 = np.cross(skin[f[:, 1]] - skin[f[:, 0]], skin[f[:, 2]] - skin[f[:, 0]])
    seg = canon.vertex_segment[f[:, 0]]
    R = np.stack([_rotation_part(m[:3, :3]) for m in comp.segment_maps])[seg]
    expected = np.einsum("fij,fj->fi", R, n0)
    a0, a1 = np.linalg.norm(n0, axis=1), np.linalg.norm(n1, axis=1)
    live = a0 > 1e-12 * max(a0.max(), 1e-300)
    degenerate = int(np.count_nonzero(live & (a1 <= 1e-9 * a0)))
    flipped = int(np.count_nonzero(live & (a1 > 1e-9 * a0) & (np.einsum("fi,fi->f", expected, n1) < 0)))
    return flipped, degenerate


def _report(canon, comp, skin, target, info, boundary) -> dict:
    names = canon.markers.names
    got = skin[np.asarray(canon.markers.vertex)]
    want = np.stack([target[n] for n in names])
    err = np.linalg.norm(got - want, axis=1)
    rms = float(np.sqrt(np.mean(err ** 2)))
    flipped, degenerate = flipped_faces(canon, comp, skin)
    fs = canon.features
    return {
        "height_m": canon.height,
        "marker_rms_m": rms, "marker_rms_fraction": rms / canon.height, "marker_max_m": float(err.max()),
        "markers": {n: float(e) for n, e in zip(names, err)},
        "flipped": flipped, "degenerate": degenerate,
        "vertices": int(len(skin)), "faces": int(len(canon.character.faces)),
        "features": {"count": int(len(fs.vertex)), "snapped": int(fs.snapped), "inserted": int(fs.inserted)},
        "widths": {k: float(v) for k, v in comp.widths.items()},
        "rbf": _jsonable(info), "boundary": _jsonable(boundary),
    }


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.floating, float)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    return x
