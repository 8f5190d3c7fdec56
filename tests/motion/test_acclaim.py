"""ASF/AMC reader: agreement with the CMU BVH conversion of the same take, bad input, fuzzing."""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile

import numpy as np
import pytest
from bvh_reference import BVH_TO_ASF, DROPPED_BY_BVH
from conftest import asset
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion import quat
from jiggle.rig.motion.acclaim import AsfSkeleton, find_asf, read_amc, read_asf
from jiggle.rig.motion.bvh import read_bvh
from jiggle.rig.motion.mocap import load_clip

ASF = "mocap/cmu_amc/01.asf"
AMC = "mocap/cmu_amc/01_01.amc"
BVH = "mocap/cmu_bvh/01_01.bvh"

@pytest.fixture(scope="module")
def cmu():
    asf = read_asf(asset(ASF))
    return asf, read_amc(asset(AMC), asf), read_bvh(asset(BVH))


def _chain_positions(clip, wp: np.ndarray) -> np.ndarray:
    """(T, J, 3) world joint positions less the world vectors (start -> tip) of every bone in
    DROPPED_BY_BVH that lies strictly above the joint, i.e. where the BVH puts that joint."""
    out = wp.copy()
    for name in DROPPED_BY_BVH:
        d = clip.index(name)
        tip_child = clip.children(d)[0]  # every child of a bone starts at its tip
        vec = wp[:, tip_child] - wp[:, d]
        for j in range(clip.num_joints):
            a = clip.parents[j]
            while a >= 0 and a != d:
                a = clip.parents[a]
            if a == d:
                out[:, j] -= vec
    return out


def test_bvh_and_amc_agree_on_every_frame(cmu):
    """World positions (0.1 mm) and rotations (0.001 deg) of every BVH joint agree with the ASF/AMC
    reading on all 2751 frames, joints matched along the bone chain (BVH_TO_ASF)."""
    _, amc, bvh = cmu
    assert amc.num_frames == bvh.num_frames == 2751
    assert amc.fps == bvh.fps == 120.0
    ar, ap = amc.world()
    br, bp = bvh.world()
    chain = _chain_positions(amc, ap)
    pos_err, rot_err = {}, {}
    for bname, aname in BVH_TO_ASF.items():
        b, a = bvh.index(bname), amc.index(aname)
        pos_err[bname] = np.linalg.norm(bp[:, b] - chain[:, a], axis=-1).max()
        rot_err[bname] = np.degrees(quat.angle(quat.mul(quat.conj(br[:, b]), ar[:, a]))).max()
    assert max(pos_err.values()) < 1e-4, pos_err
    assert max(rot_err.values()) < 1e-3, rot_err
    # Below the dropped bones the raw world positions agree directly, joint for joint.
    below = ["Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "RHipJoint",
             "RightUpLeg", "RightLeg", "RightFoot", "RightToeBase", "LowerBack", "Spine", "Spine1"]
    for bname in below:
        e = np.linalg.norm(bp[:, bvh.index(bname)] - ap[:, amc.index(BVH_TO_ASF[bname])], axis=-1)
        assert e.max() < 1e-4, (bname, e.max())
    # Above them the BVH is short by exactly the thorax (2.06488 units * 0.056444 m): the reason
    # for the chain correction, and a check that the correction is not hiding a real error.
    raw = np.linalg.norm(bp[:, bvh.index("Head")] - ap[:, amc.index("head")], axis=-1)
    np.testing.assert_allclose(raw, 2.06488 * 0.0254 / 0.45, atol=1e-4)


def test_units_axes_and_layout(cmu):
    asf, amc, _ = cmu
    assert asf.metres_per_unit == pytest.approx(0.0254 / 0.45)
    assert asf.angle_unit == "deg"
    assert amc.joint_names[0] == "root" and len(amc.joint_names) == 31
    assert np.all(amc.rest_rotations == quat.identity((31,)))
    # Z-up: the head is above the feet at rest and on every frame.
    _, ap = amc.world()
    assert np.all(ap[:, amc.index("head"), 2] > ap[:, amc.index("lfoot"), 2] + 1.0)
    # lfemur's tip (ltibia's offset): direction (0.34202, -0.939693, 0) * 7.1578 units, Y-up -> Z-up.
    d = np.array([0.34202, 0.0, -0.939693]) * 7.1578 * asf.metres_per_unit
    np.testing.assert_allclose(amc.offsets[amc.index("ltibia")], d, atol=1e-6)  # direction normalised
    # Leaf bones carry end sites at their tips; children of the root sit at the root.
    leaves = {amc.joint_names[e] for e in amc.end_parents}
    assert leaves == {"ltoes", "rtoes", "head", "lfingers", "lthumb", "rfingers", "rthumb"}
    assert np.all(amc.offsets[[amc.index(n) for n in ("lhipjoint", "rhipjoint", "lowerback")]] == 0)
    lf = asf.bone("lfemur")
    assert lf.dof == ("rx", "ry", "rz") and lf.limits[0] == pytest.approx(np.radians([-160, 20]))


def test_rest_clip_and_dispatch(cmu):
    asf, amc, _ = cmu
    rest = asf.rest_clip()
    assert rest.num_frames == 1 and rest.joint_names == amc.joint_names
    np.testing.assert_allclose(rest.offsets, amc.offsets)
    via_asf = load_clip(asset(ASF))
    np.testing.assert_allclose(via_asf.translations, rest.translations)
    via_amc = load_clip(asset(AMC))  # finds 01.asf beside it
    np.testing.assert_allclose(via_amc.rotations, amc.rotations)
    assert find_asf(asset(AMC)) == os.path.abspath(asset(ASF))


def test_fps_and_radians(tmp_path, cmu):
    asf, amc, _ = cmu
    lines = open(asset(AMC)).read().splitlines()
    short = _first_frames(lines, 5)
    # The same values in radians give the same clip.
    rad = []
    for ln in short:
        t = ln.split()
        if ln.strip() == ":DEGREES":
            rad.append(":RADIANS")
        elif t and not t[0].isdigit() and not ln.startswith((":", "#")):
            vals = np.array(t[1:], float)
            if t[0] == "root":
                vals[3:] = np.radians(vals[3:])
            else:
                vals = np.radians(vals)
            rad.append(" ".join([t[0]] + [repr(float(v)) for v in vals]))
        else:
            rad.append(ln)
    p = tmp_path / "rad.amc"
    p.write_text("\n".join(rad) + "\n")
    c = read_amc(p, asf, fps=60)
    assert c.fps == 60.0 and c.num_frames == 5
    np.testing.assert_allclose(c.rotations, amc.rotations[:5], atol=1e-12)
    np.testing.assert_allclose(c.translations, amc.translations[:5], atol=1e-12)
    with pytest.raises(InputError, match="fps"):
        read_amc(p, asf, fps=0)


# ---------------------------------------------------------------------------------------- bad input
def _first_frames(lines: list[str], n: int) -> list[str]:
    """Header and the first n frames of AMC lines."""
    out, frames = [], 0
    for ln in lines:
        if ln.strip().isdigit():
            frames += 1
            if frames > n:
                break
        out.append(ln)
    return out


@pytest.fixture(scope="module")
def amc_lines():
    return _first_frames(open(asset(AMC)).read().splitlines(), 3)


@pytest.fixture(scope="module")
def asf_text():
    return open(asset(ASF)).read()


def _expect(tmp_path, amc_lines, asf, line, pattern, field=None, name="bad.amc"):
    p = tmp_path / name
    p.write_text("\n".join(amc_lines) + "\n")
    with pytest.raises(InputError, match=pattern) as e:
        read_amc(p, asf)
    assert e.value.path == str(p)
    assert e.value.line == line
    if field is not None:
        assert e.value.field == field
    return e.value


def _line_of(lines, prefix, nth=0):
    """1-based number of the nth line starting with prefix."""
    hits = [i + 1 for i, ln in enumerate(lines) if ln.startswith(prefix)]
    return hits[nth]


def test_truncated_frame_missing_bones(tmp_path, amc_lines, cmu):
    cut = amc_lines[:_line_of(amc_lines, "rfemur", 2) - 1]  # the last frame stops before rfemur
    _expect(tmp_path, cut, cmu[0], _line_of(cut, "3"), r"frame 3 lacks bone\(s\) lfemur, lfoot.*truncated",
            "frame")


def test_truncated_mid_line(tmp_path, amc_lines, cmu):
    cut = list(amc_lines)
    k = _line_of(cut, "lhumerus", 2) - 1
    cut[k] = cut[k][:len("lhumerus 17.2")]
    _expect(tmp_path, cut[:k + 1], cmu[0], k + 1, r"expected 3 values \(rx ry rz\), found 1", "lhumerus")


def test_wrong_value_count(tmp_path, amc_lines, cmu):
    bad = list(amc_lines)
    k = _line_of(bad, "ltibia", 1) - 1
    bad[k] += " 4.5"
    _expect(tmp_path, bad, cmu[0], k + 1, r"expected 1 values \(rx\), found 2", "ltibia")


def test_non_numeric(tmp_path, amc_lines, cmu):
    bad = list(amc_lines)
    k = _line_of(bad, "head", 1) - 1
    bad[k] = "head 10.5 abc -0.3"
    _expect(tmp_path, bad, cmu[0], k + 1, r"expected a number, found 'abc'", "head")


@pytest.mark.parametrize("tok", ["nan", "inf", "-Infinity", "1e999"])
def test_nan_and_inf(tmp_path, amc_lines, cmu, tok):
    bad = list(amc_lines)
    k = _line_of(bad, "root", 2) - 1
    bad[k] = f"root 9.3 17.8 {tok} -2.0 -7.5 -3.2"
    _expect(tmp_path, bad, cmu[0], k + 1, "not a finite number", "root")


def test_zero_frames(tmp_path, amc_lines, cmu):
    header = amc_lines[:_line_of(amc_lines, "1") - 1]
    _expect(tmp_path, header, cmu[0], len(header), "no frames", "frame")


def test_bone_not_in_skeleton(tmp_path, amc_lines, cmu):
    bad = list(amc_lines)
    k = _line_of(bad, "head", 0)
    bad.insert(k, "tail 1 2 3")
    _expect(tmp_path, bad, cmu[0], k + 1, r"bone 'tail' is not in the skeleton 01.asf", "tail")


def test_frame_numbers_must_count_up(tmp_path, amc_lines, cmu):
    bad = list(amc_lines)
    k = _line_of(bad, "3") - 1
    bad[k] = "7"
    _expect(tmp_path, bad, cmu[0], k + 1, "frame number 7 follows frame 2", "frame")


def test_missing_files(tmp_path, cmu):
    with pytest.raises(InputError, match="not found") as e:
        read_amc(tmp_path / "nope.amc", cmu[0])
    assert e.value.path == str(tmp_path / "nope.amc")
    with pytest.raises(InputError, match="not found") as e:
        read_asf(tmp_path / "nope.asf")
    assert e.value.path == str(tmp_path / "nope.asf")


def test_find_asf_needs_exactly_one(tmp_path, amc_lines, asf_text):
    amc = tmp_path / "a.amc"
    amc.write_text("\n".join(amc_lines))
    with pytest.raises(InputError, match="no .asf file.*pass the skeleton") as e:
        find_asf(amc)
    assert e.value.path == str(amc) and e.value.field == "skeleton"
    (tmp_path / "x.asf").write_text(asf_text)
    assert find_asf(amc) == str(tmp_path / "x.asf")
    (tmp_path / "y.ASF").write_text(asf_text)
    with pytest.raises(InputError, match="2 .asf files"):
        find_asf(amc)


def _asf_error(tmp_path, text, line, pattern, field):
    p = tmp_path / "bad.asf"
    p.write_text(text)
    with pytest.raises(InputError, match=pattern) as e:
        read_asf(p)
    assert (e.value.path, e.value.line, e.value.field) == (str(p), line, field)


def test_asf_hierarchy_names_unknown_bone(tmp_path, asf_text):
    text = asf_text.replace("    lhipjoint lfemur\n", "    lhipjoint lfemur tail\n")
    line = text.splitlines().index("    lhipjoint lfemur tail") + 1
    _asf_error(tmp_path, text, line, r"unknown bone 'tail'", "hierarchy")


def test_asf_unknown_angle_unit(tmp_path, asf_text):
    text = asf_text.replace("  angle deg", "  angle grad")
    line = text.splitlines().index("  angle grad") + 1
    _asf_error(tmp_path, text, line, r"unknown angle unit 'grad'", "units angle")


def test_asf_bad_fields(tmp_path, asf_text):
    lines = asf_text.splitlines()
    k = lines.index("     length 7.1578  ")
    _asf_error(tmp_path, "\n".join(lines[:k] + ["     length -1"] + lines[k + 1:]), k + 1,
               "length must be >= 0", "length")
    _asf_error(tmp_path, "\n".join(lines[:k] + ["     length nan"] + lines[k + 1:]), k + 1,
               "not a finite number", "length")
    _asf_error(tmp_path, asf_text.replace("    dof rx ry rz\n", "    dof rx ry rq\n", 1),
               lines.index("    dof rx ry rz") + 1, "dof must list", "dof")
    # A loop: lfemur becomes its own grandchild's child and loses its path to the root.
    text = asf_text.replace("    lhipjoint lfemur\n", "    ltibia lfemur\n")
    _asf_error(tmp_path, text, text.splitlines().index("    ltibia lfemur") + 1,
               "not connected to the root", "hierarchy")


def test_asf_radians_and_units(tmp_path, asf_text, cmu):
    """angle rad: the ASF's axis angles are read in radians; length scales every offset."""
    lines = []
    for ln in asf_text.splitlines():
        t = ln.split()
        if t and t[0] == "axis" and len(t) == 5:
            ln = "axis " + " ".join(repr(float(np.radians(float(v)))) for v in t[1:4]) + " " + t[4]
        elif t and t[0] == "limits":
            ln = "limits " + ln.split("limits", 1)[1]
        lines.append(ln)
    text = "\n".join(lines).replace("angle deg", "angle rad").replace("length 0.45", "length 0.9")
    p = tmp_path / "rad.asf"
    p.write_text(text)
    asf = read_asf(p)
    ref = cmu[0]
    assert asf.angle_unit == "rad" and asf.metres_per_unit == pytest.approx(ref.metres_per_unit / 2)
    for a, b in zip(asf.bones, ref.bones):
        np.testing.assert_allclose(a.axis, b.axis, atol=1e-12)
    np.testing.assert_allclose(asf.rest_clip().offsets, ref.rest_clip().offsets / 2, atol=1e-12)


# ---------------------------------------------------------------------------------------- fuzzing
JUNK = ["nan", "inf", "-inf", "1e308", "-1e309", "abc", "", "(", ")", "begin", "end", ":root",
        "root", "lfemur", "1", "0", "-", "1e-320", "\u00b2", "\t", "begin end", "dof rx", "#"]


@st.composite
def mutations(draw, n_lines: int):
    """A list of edits: (kind, line index, token index, junk)."""
    ops = []
    for _ in range(draw(st.integers(1, 4))):
        ops.append((draw(st.sampled_from(["truncate", "delete", "duplicate", "replace_line",
                                          "replace_token", "insert"])),
                    draw(st.integers(0, n_lines - 1)), draw(st.integers(0, 6)),
                    draw(st.sampled_from(JUNK) | st.text(max_size=12)),
                    draw(st.floats(0.0, 1.0))))
    return ops


def _mutate(text: str, ops) -> str:
    lines = text.splitlines()
    for kind, i, t, junk, frac in ops:
        if not lines:
            break
        i %= len(lines)
        if kind == "truncate":
            cut = "\n".join(lines)
            return cut[:int(frac * len(cut))]
        if kind == "delete":
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "replace_line":
            lines[i] = junk
        elif kind == "insert":
            lines.insert(i, junk)
        else:
            toks = lines[i].split()
            if toks:
                toks[t % len(toks)] = junk
                lines[i] = " ".join(toks)
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def fuzz_dir():
    d = tempfile.mkdtemp(prefix="jiggle_acclaim_fuzz_")
    yield d
    shutil.rmtree(d, ignore_errors=True)


FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))


def _only_input_errors(fn):
    with contextlib.suppress(InputError):  # a clear user error is a pass; anything else fails the fuzz
        fn()


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_fuzz_amc(data, fuzz_dir):
    """Mutated AMC files (200 frames of 01_01) raise InputError or read; nothing else escapes."""
    asf = read_asf(asset(ASF))
    base = "\n".join(_first_frames(open(asset(AMC)).read().splitlines(), 200))
    text = _mutate(base, data.draw(mutations(base.count("\n") + 1)))
    p = os.path.join(fuzz_dir, "fuzz.amc")
    with open(p, "w", encoding="utf-8", errors="surrogatepass") as fh:
        fh.write(text)
    _only_input_errors(lambda: read_amc(p, asf))


@FUZZ
@given(data=st.data())
def test_fuzz_asf(data, fuzz_dir):
    """Mutated ASF files, read alone and with a 20-frame AMC: InputError or a clip, nothing else."""
    base = open(asset(ASF)).read()
    text = _mutate(base, data.draw(mutations(base.count("\n") + 1)))
    p = os.path.join(fuzz_dir, "fuzz.asf")
    with open(p, "w", encoding="utf-8", errors="surrogatepass") as fh:
        fh.write(text)
    amc = os.path.join(fuzz_dir, "short.amc")
    if not os.path.exists(amc):
        with open(amc, "w") as fh:
            fh.write("\n".join(_first_frames(open(asset(AMC)).read().splitlines(), 20)) + "\n")

    def run():
        asf = read_asf(p)
        assert isinstance(asf, AsfSkeleton)
        asf.rest_clip()
        read_amc(amc, asf)
    _only_input_errors(run)


# ---------------------------------------------------------------------------------------- no assets
TINY_ASF = """# a two-bone skeleton: dofs listed out of order, a subset, and a length dof
:version 1.10
:name tiny
:units
  mass 1.0
  length 1.0
  angle deg
:root
  order TX TY TZ RX RY RZ
  axis XYZ
  position 0 0 0
  orientation 0 0 0
:bonedata
  begin
    id 1
    name a
    direction 0 1 0
    length 10
    axis 0 0 90 XYZ
    dof rz rx l
    limits (-180 180) (-90 90)
           (-inf inf)
  end
  begin
    id 2
    name b
    direction 1 0 0
    length 5
    axis 10 20 30 XYZ
    dof ry
  end
:hierarchy
  begin
    root a
    a b
  end
"""
TINY_AMC = """:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 10 -20 30
a 30 40 2
b 50
"""


def test_tiny_skeleton_by_hand(tmp_path):
    """World positions of a hand-made skeleton against matrices written out independently:
    M = Rz Ry Rx whatever the dof order, L = C M C^-1, `l` lengthens the bone, inches -> metres,
    Y-up -> Z-up."""
    from scipy.spatial.transform import Rotation
    (tmp_path / "tiny.asf").write_text(TINY_ASF)
    (tmp_path / "tiny.amc").write_text(TINY_AMC)
    clip = load_clip(tmp_path / "tiny.amc")  # finds tiny.asf beside it
    assert clip.joint_names == ("root", "a", "b") and clip.fps == 120.0

    def R(axis, deg):
        return Rotation.from_euler(axis, deg, degrees=True).as_matrix()

    L_root = R("z", 30) @ R("y", -20) @ R("x", 10)
    C_a = R("z", 90)
    L_a = C_a @ (R("z", 30) @ R("x", 40)) @ C_a.T
    C_b = R("z", 30) @ R("y", 20) @ R("x", 10)
    L_b = C_b @ R("y", 50) @ C_b.T
    root = np.array([1.0, 2, 3])
    b = root + L_root @ L_a @ np.array([0.0, 12, 0])  # length 10 + l 2
    tip = b + L_root @ L_a @ L_b @ np.array([5.0, 0, 0])
    yz = lambda v: np.array([v[0], -v[2], v[1]]) * 0.0254  # noqa: E731
    wr, wp = clip.world()
    np.testing.assert_allclose(wp[0], [yz(root), yz(root), yz(b)], atol=1e-12)
    np.testing.assert_allclose(clip.end_world(wr, wp)[0, 0], yz(tip), atol=1e-12)
    asf = read_asf(tmp_path / "tiny.asf")
    assert asf.bone("a").limits[2] == (-np.inf, np.inf)
    assert asf.bone("a").dof == ("rz", "rx", "l")
