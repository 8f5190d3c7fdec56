"""Generated bodies: one closed genus-0 surface around any skeleton, sized by it, with fat volumes.

Inside/outside is judged with the generalized winding number (1 inside a closed outward mesh, 0
outside), computed here in NumPy so the tests need no spatial index library.
"""
import dataclasses

import numpy as np
import pytest
import trimesh
from conftest import asset
from meshes import winding_numbers
from scipy.spatial import cKDTree

from jiggle.rig.character.body import BodyOptions, generate_body
from jiggle.rig.motion import quat
from jiggle.rig.skin.skinning import pose_character

COARSE = 8000  # vertices: enough for shape tests, fast


def demo_clip():
    from jiggle.sim.bake.scene import load_scene
    return load_scene("scenes/default.toml").clip


def cmu_clip():
    from jiggle.rig.motion.bvh import read_bvh
    return read_bvh(asset("mocap/cmu_bvh/01_01.bvh"))


def mjcf_clip():
    from jiggle.rig.motion.mjcf_skeleton import read_mjcf_skeleton
    return read_mjcf_skeleton(asset("mjcf/humanoid_CMU.xml"))


def cesium_clip():
    from jiggle.rig.motion.gltf_skeleton import read_gltf_skeleton
    return read_gltf_skeleton(asset("characters/CesiumMan.glb")).to_clip()


SKELETONS = {"demo": demo_clip, "cmu_bvh": cmu_clip, "humanoid_CMU": mjcf_clip, "CesiumMan": cesium_clip}
_cache = {}


def body_of(name: str, **options):
    """Generated once per skeleton and options within the test session."""
    key = (name, tuple(sorted(options.items())))
    if key not in _cache:
        clip = SKELETONS[name]()
        _cache[key] = (clip, generate_body(clip, BodyOptions(**options)))
    return _cache[key]



def signed_distance(v: np.ndarray, f: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(P,) metres, positive inside: distance to the nearest vertex (within half an edge of the
    distance to the surface), signed by the winding number."""
    d, _ = cKDTree(v).query(p)
    return np.where(winding_numbers(v, f, p) > 0.5, d, -d)


def skeleton_points(clip):
    """Rest-pose world positions of the joints (J, 3) and end sites (E, 3)."""
    rot, pos = clip.rest_world()
    ends = clip.end_world(rot[None], pos[None])[0] if len(clip.end_parents) else np.zeros((0, 3))
    return pos, ends


def check_closed_genus0(body):
    m = trimesh.Trimesh(body.vertices, body.faces, process=False)
    assert m.is_watertight
    assert m.is_winding_consistent
    assert m.volume > 0  # faces wind outward
    assert m.euler_number == 2  # genus 0: no handle where a limb touches the trunk
    assert len(m.split(only_watertight=False)) == 1
    assert body.faces.dtype == np.int32 and body.vertices.dtype == np.float64
    assert not body.vertices.flags.writeable


@pytest.mark.parametrize("name", list(SKELETONS))
def test_default_body_is_one_closed_genus0_surface_of_10k_to_40k_vertices(name):
    clip, body = body_of(name)
    check_closed_genus0(body)
    assert 10_000 <= len(body.vertices) <= 40_000
    print(f"{name}: {len(body.vertices)} vertices, voxel {1000 * body.voxel:.1f} mm, "
          f"{body.timings['total']:.2f} s")


def test_resolution_option_sets_the_vertex_count():
    counts = [len(body_of("demo", resolution=r)[1].vertices) for r in (12_000, 20_000, 35_000)]
    assert counts == sorted(counts) and len(set(counts)) == 3
    assert 10_000 <= counts[0] and counts[-1] <= 40_000
    for r, n in zip((12_000, 20_000, 35_000), counts):
        assert abs(n / r - 1) < 0.15


@pytest.mark.parametrize("name", list(SKELETONS))
def test_joints_inside_and_body_spans_the_skeleton(name):
    clip, body = body_of(name, resolution=COARSE)
    check_closed_genus0(body)
    v, f = body.vertices, body.faces
    joints, ends = skeleton_points(body.bind)  # the pose it was built in
    np.testing.assert_allclose(body.joint_positions, joints)
    assert signed_distance(v, f, joints).min() > 0  # every joint inside
    if len(ends):  # end sites are bone tips: inside or on the surface
        assert signed_distance(v, f, ends).min() > -body.voxel
    pts = np.concatenate([joints, ends])
    lo, hi = pts.min(0), pts.max(0)
    ext = hi[2] - lo[2]
    # the top is the head (up to 0.1 of the height above the last neck joint without a head end
    # site), the bottom the soles just under the lowest joint
    assert -0.01 < v[:, 2].max() - hi[2] < 0.1 * ext
    assert -0.03 * ext < v[:, 2].min() - lo[2] < 0.005
    assert np.all(v.min(0)[:2] < lo[:2]) and np.all(v.max(0)[:2] > hi[:2])  # hands, feet covered


def scaled(clip, s: float):
    return dataclasses.replace(clip, offsets=clip.offsets * s, translations=clip.translations * s,
                               end_offsets=clip.end_offsets * s)


@pytest.mark.parametrize("name", ["demo", "cmu_bvh"])
def test_body_scales_with_the_skeleton(name):
    clip = SKELETONS[name]()
    lean = BodyOptions(resolution=COARSE, belly=0, chest=0, glutes=0, upper_arms=0)  # fat is in metres
    small, big = generate_body(clip, lean), generate_body(scaled(clip, 2.0), lean)
    ratio = np.ptp(big.vertices, axis=0) / np.ptp(small.vertices, axis=0)
    np.testing.assert_allclose(ratio, 2.0, rtol=0.03)
    assert abs(big.stature / small.stature - 2) < 1e-9
    check_closed_genus0(big)


def test_front_is_found_from_the_feet():
    clip = demo_clip()
    body = body_of("demo", resolution=COARSE)[1]
    np.testing.assert_allclose(body.front, [0, -1, 0], atol=1e-9)  # the demo faces -Y
    names = {fv.name: fv for fv in body.fat}
    assert names["belly"].center[1] < 0 and names["glute_L"].center[1] > 0  # belly front, glutes back
    assert names["chest_L"].center[0] > 0 > names["chest_R"].center[0]      # its left is +X
    # turned half round about Z, it faces +Y and its left side is -X
    q = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi)
    rest = clip.rest_rotations.copy()
    rest[0] = quat.mul(q, rest[0])
    off = clip.offsets.copy()
    off[0] = quat.rotate(q, off[0])
    turned = dataclasses.replace(clip, rest_rotations=rest, offsets=off, rotations=rest[None],
                                 translations=off[None])
    tb = generate_body(turned, BodyOptions(resolution=COARSE))
    np.testing.assert_allclose(tb.front, [0, 1, 0], atol=1e-9)
    tn = {fv.name: fv for fv in tb.fat}
    assert tn["belly"].center[1] > 0 and tn["chest_L"].center[0] < 0


def test_belly_fat_adds_volume_in_front_of_the_belly():
    clip = demo_clip()
    lean = generate_body(clip, BodyOptions(resolution=COARSE, belly=0.0))
    fat = generate_body(clip, BodyOptions(resolution=COARSE, belly=0.05))
    assert "belly" not in [fv.name for fv in lean.fat]
    belly = next(fv for fv in fat.fat if fv.name == "belly")
    vol = [trimesh.Trimesh(b.vertices, b.faces, process=False).volume for b in (lean, fat)]
    assert vol[1] > vol[0] * 1.02

    def front_at_belly(b):
        """How far the surface reaches forward around the belly's centre line and height."""
        v = b.vertices
        near = (np.abs(v[:, 0] - belly.center[0]) < 0.04) & (np.abs(v[:, 2] - belly.center[2]) < 0.04)
        return (v[near] @ b.front).max()

    grow = front_at_belly(fat) - front_at_belly(lean)
    assert 0.6 * 0.05 < grow < 1.3 * 0.05  # the option is metres of extra thickness at the front


@pytest.mark.parametrize("name", ["demo", "cmu_bvh"])
def test_fat_volumes_lie_inside_the_body(name):
    clip, body = body_of(name, resolution=COARSE)
    assert {fv.name for fv in body.fat} == {"belly", "chest_L", "chest_R", "glute_L", "glute_R",
                                            "upper_arm_L", "upper_arm_R"}
    u = np.random.default_rng(0).normal(size=(42, 3))
    u = np.concatenate([np.eye(3), -np.eye(3), u / np.linalg.norm(u, axis=1, keepdims=True)])
    for fv in body.fat:
        assert 0 <= fv.joint < clip.num_joints
        np.testing.assert_allclose(fv.axes @ fv.axes.T, np.eye(3), atol=1e-9)
        ellipsoid = fv.center + (u * fv.radii) @ fv.axes  # points on its surface
        assert signed_distance(body.vertices, body.faces, fv.center[None])[0] > 0
        assert signed_distance(body.vertices, body.faces, ellipsoid).min() > -0.5 * body.voxel, fv.name


def test_render_mesh_writes_a_png_of_the_requested_size(tmp_path):
    from PIL import Image

    from jiggle.sim.app.report.mesh_render import render_mesh
    clip, body = body_of("demo", resolution=COARSE)
    joints, ends = skeleton_points(body.bind)  # the pose it was built in
    bones = np.array([(joints[p], joints[j]) for j, p in enumerate(clip.parents) if p >= 0])
    path = tmp_path / "body.png"
    out = render_mesh(body.vertices, body.faces, path, views=("front", "side"), title="demo",
                      size=(640, 360), overlay_lines=bones)
    assert out == str(path) and path.stat().st_size > 0
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (360, 640, 3)
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50  # a picture, not a blank window
    labels = np.argmax(np.abs(body.vertices[:, :1]), axis=1) + (body.vertices[:, 0] > 0)  # int scalars
    render_mesh(body.vertices, body.faces, path, scalars=labels, views=("iso",), size=(300, 300))
    assert np.asarray(Image.open(path)).shape[:2] == (300, 300)
    assert not list(tmp_path.glob(".*tmp*"))  # the temporary file was renamed


def _upper_arm_hang_deg(clip) -> list[float]:
    """Angle of each upper arm from straight down, degrees, in the clip's rest pose."""
    from jiggle.rig.character.body import _analyse, _upper_arm
    sk = _analyse(clip)
    out = []
    for ch in sk.chains:
        if ch.kind == "arm":
            u, tip = _upper_arm(sk, ch)
            d = sk.pos[tip] - sk.pos[u]
            out.append(float(np.degrees(np.arccos(-d[2] / np.linalg.norm(d)))))
    return out


def test_hanging_arms_are_swung_out_for_the_bind_pose():
    from jiggle.rig.character.body import bind_pose
    clip = demo_clip()
    assert max(_upper_arm_hang_deg(clip)) < 5, "the demo's arms hang straight down at rest"
    bind = bind_pose(clip, 40.0)
    np.testing.assert_allclose(_upper_arm_hang_deg(bind), 40.0, atol=1e-6)
    # only the arms moved: legs, spine and head keep their rest positions
    _, p0 = clip.rest_world()
    _, p1 = bind.rest_world()
    moved = np.linalg.norm(p1 - p0, axis=1) > 1e-9
    assert {clip.joint_names[j] for j in np.nonzero(moved)[0]} == {"l_forearm", "l_hand", "r_forearm", "r_hand"}
    # hands go outwards, away from the body's mid-plane
    for side in ("l_hand", "r_hand"):
        j = clip.index(side)
        assert abs(p1[j, 0]) > abs(p0[j, 0]) + 0.2
    # a T-pose is left alone; 0 keeps the rest pose
    cmu = cmu_clip()
    np.testing.assert_allclose(bind_pose(cmu, 40.0).rest_rotations, cmu.rest_rotations)
    np.testing.assert_allclose(bind_pose(clip, 0.0).rest_rotations, clip.rest_rotations)


def test_generated_character_is_bound_in_its_build_pose():
    """The body's character skins back to its rest skin at the bind pose and follows the clip."""
    from jiggle.rig.character.load import body_character
    from jiggle.sim.app.skin_pass import skin_motion
    from jiggle.sim.drive.motion import drive_kinematic
    clip = demo_clip()
    c = body_character(clip, BodyOptions(resolution=COARSE))
    np.testing.assert_allclose(pose_character(c, c.bind_world), c.vertices, atol=1e-5)
    motion = drive_kinematic(clip, clip.times[:31])
    skinned = skin_motion(c, motion, frames=[0, 30])
    assert np.all(np.isfinite(skinned))
    # at 0.5 s the arms are up: the highest vertex is a hand, well above the head's top at rest
    assert skinned[1][:, 2].max() > c.vertices[:, 2].max() + 0.3
    # the feet stay on the floor within a few cm
    assert abs(skinned[0][:, 2].min() - c.vertices[:, 2].min()) < 0.05
