"""BVH reader: hierarchies and channel layouts against an independent FK, CMU facts, bad input, fuzz."""

import bvh_reference as ref
import numpy as np
import pytest
from bvh_reference import write_odd_bvh
from conftest import CMU_BVH, asset
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jiggle.rig.base.errors import InputError
from jiggle.rig.motion.bvh import CMU_UNIT, read_bvh


def test_any_hierarchy_matches_independent_fk(tmp_path):
    p = write_odd_bvh(tmp_path / "odd.bvh")
    clip = read_bvh(p, scale=0.01, tpose="keep")
    joints, _, frames, dt = ref.parse(p.read_text())
    want = ref.to_zup_metres(ref.world_positions(joints, frames), 0.01)
    _, got = clip.world()
    assert clip.joint_names == ("base", "arm", "slider", "fixed", "twist", "prop")
    assert list(clip.parents) == [-1, 0, 1, 2, 0, -1]
    assert clip.fps == 25.0 and clip.num_frames == 40
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert len(clip.end_parents) == 3
    assert clip.animated_translation.tolist() == [True, False, True, False, False, True]


def test_y_up_becomes_z_up_and_z_up_files_stay(tmp_path):
    p = write_odd_bvh(tmp_path / "odd.bvh", frames=3)
    y = read_bvh(p, scale=1.0, tpose="keep")
    z = read_bvh(p, scale=1.0, up="z", tpose="keep")
    _, py = y.world()
    _, pz = z.world()
    np.testing.assert_allclose(py, np.stack([pz[..., 0], -pz[..., 2], pz[..., 1]], -1), atol=1e-9)


@pytest.mark.parametrize("name", CMU_BVH)
def test_cmu_files_units_tpose_and_fk(name):
    path = asset(f"mocap/cmu_bvh/{name}.bvh")
    clip = read_bvh(path)
    raw_joints, _, frames, _ = ref.parse(path.read_text())
    assert clip.meta["tpose"] == "detected and skipped"
    assert clip.num_frames == frames.shape[0] - 1 and clip.fps == 120.0
    assert clip.meta["metres_per_unit"] == CMU_UNIT
    sel = slice(1, None, 7)  # every 7th capture frame keeps the pure-Python reference quick
    want = ref.to_zup_metres(ref.world_positions(raw_joints, frames[sel]), CMU_UNIT)
    _, got = clip.world()
    np.testing.assert_allclose(got[::7], want, atol=1e-9)
    # a standing adult: hips about 0.9-1.0 m above the feet, Z up
    _, rest = clip.rest_world()
    hips_height = rest[0, 2] - rest[:, 2].min()
    assert 0.75 < hips_height < 1.1


def test_tpose_options_and_no_false_detection(tmp_path):
    path = asset("mocap/cmu_bvh/09_11.bvh")
    assert read_bvh(path, tpose="keep").num_frames == 166
    assert read_bvh(path, tpose="skip").num_frames == 165
    # the same capture without its added first frame: nothing to detect, nothing dropped
    lines = path.read_text().splitlines()
    m = lines.index("MOTION")
    trimmed = lines[:m + 1] + ["Frames: 165"] + lines[m + 2:m + 3] + lines[m + 4:]
    (tmp_path / "no_tpose.bvh").write_text("\n".join(trimmed) + "\n")
    clip = read_bvh(tmp_path / "no_tpose.bvh")
    assert clip.meta["tpose"] == "none detected" and clip.num_frames == 165


def test_units_guess_from_height(tmp_path):
    text = ("HIERARCHY\nROOT hip\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation "
            "Yrotation\nJOINT head\n{\nOFFSET 0 {h} 0\nCHANNELS 3 Zrotation Xrotation Yrotation\nEnd Site\n{\n"
            "OFFSET 0 {h} 0\n}\n}\n}\nMOTION\nFrames: 2\nFrame Time: 0.01\n0 90 0 0 0 0 0 0 0\n0 90 0 0 0 0 0 0 0\n")
    (tmp_path / "cm.bvh").write_text(text.replace("{h}", "80"))
    cm = read_bvh(tmp_path / "cm.bvh")
    assert cm.meta["metres_per_unit"] == 0.01 and "centimetres" in cm.meta["units"]
    assert cm.rest_world()[1][1, 2] == pytest.approx(0.8)
    (tmp_path / "m.bvh").write_text(text.replace("{h}", "0.8"))
    assert read_bvh(tmp_path / "m.bvh").meta["metres_per_unit"] == 1.0


# ------------------------------------------------------------------------------------ bad input
GOOD = """HIERARCHY
ROOT hip
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT knee
  {
    OFFSET 0 -10 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -10 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.01
0 20 0 0 0 0 0 0 0
0 20 0 0 0 0 10 0 0
0 20 0 0 0 0 20 0 0
"""

BAD_CASES = {
    # case: (text, expected line or None, words in the message)
    "truncated motion": (GOOD.rsplit("\n", 2)[0] + "\n", 20, "expected 3 frame lines"),
    "truncated hierarchy": ("\n".join(GOOD.splitlines()[:8]) + "\n", 8, "truncated"),
    "short frame line": (GOOD.replace("0 20 0 0 0 0 10 0 0", "0 20 0 0 0 0 10 0"), 20, "expected 9 values"),
    "channel count mismatch": (GOOD.replace("CHANNELS 3 Zrotation", "CHANNELS 4 Zrotation"), 9, "CHANNELS says 4"),
    "unknown channel": (GOOD.replace("3 Zrotation Yrotation Xrotation", "3 Zrotation Yrotation Wrotation"), 9,
                        "unknown channel"),
    "non-numeric value": (GOOD.replace("0 20 0 0 0 0 10 0 0", "0 20 0 0 zero 0 10 0 0"), 20, "'zero'"),
    "non-numeric offset": (GOOD.replace("OFFSET 0 -10 0", "OFFSET 0 -1O 0", 1), 8, "'-1O'"),
    "nan value": (GOOD.replace("0 20 0 0 0 0 20 0 0", "0 20 0 nan 0 0 20 0 0"), 21, "finite"),
    "inf value": (GOOD.replace("0 20 0 0 0 0 20 0 0", "0 20 0 0 0 0 inf 0 0"), 21, "finite"),
    "zero frames": (GOOD.replace("Frames: 3", "Frames: 0"), 17, "0 frames"),
    "negative frame time": (GOOD.replace("Frame Time: 0.01", "Frame Time: -0.01"), 18, "Frame Time must be > 0"),
    "zero frame time": (GOOD.replace("Frame Time: 0.01", "Frame Time: 0"), 18, "Frame Time must be > 0"),
    "extra frames": (GOOD + "0 20 0 0 0 0 20 0 0\n", 22, "more frame lines"),
    "no hierarchy": ("MOTION\nFrames: 1\n", 1, "HIERARCHY"),
    "unbalanced braces": (GOOD.replace("  }\n}\nMOTION", "  }\nMOTION"), 15, "closed"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_names_file_and_line(tmp_path, case):
    text, line, words = BAD_CASES[case]
    p = tmp_path / "bad.bvh"
    p.write_text(text)
    with pytest.raises(InputError) as e:
        read_bvh(p)
    assert e.value.path == str(p)
    assert e.value.line == line, str(e.value)
    assert words in str(e.value)


def test_missing_directory_and_binary_files(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_bvh(tmp_path / "nope.bvh")
    with pytest.raises(InputError, match="directory"):
        read_bvh(tmp_path)
    (tmp_path / "bin.bvh").write_bytes(bytes(range(256)))
    with pytest.raises(InputError, match="UTF-8"):
        read_bvh(tmp_path / "bin.bvh")
    (tmp_path / "good.bvh").write_text(GOOD)
    for kw in ({"scale": -1.0}, {"up": "x"}, {"tpose": "maybe"}):
        with pytest.raises(InputError):
            read_bvh(tmp_path / "good.bvh", **kw)


# ------------------------------------------------------------------------------------ fuzz
def _seed_text():
    path = asset("mocap/cmu_bvh/09_11.bvh")
    lines = path.read_text().splitlines()
    m = lines.index("MOTION")
    return lines[:m + 1] + ["Frames: 12"] + [lines[m + 2]] + lines[m + 3:m + 15]


JUNK = ["", "{", "}", "nan", "-inf", "1e400", "abc", "ROOT", "JOINT x", "End Site", "CHANNELS 9", "OFFSET 1",
        "MOTION", "Frames: -3", "Frame Time: 0", "0 0 0", "\t", "\x00", "é"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_fuzz_only_input_errors(tmp_path_factory, data):
    lines = list(_seed_text())
    for _ in range(data.draw(st.integers(1, 4))):
        kind = data.draw(st.sampled_from(["delete", "duplicate", "replace_line", "replace_token", "truncate"]))
        i = data.draw(st.integers(0, len(lines) - 1))
        if kind == "delete" and len(lines) > 1:
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "replace_line":
            lines[i] = data.draw(st.sampled_from(JUNK))
        elif kind == "replace_token":
            toks = lines[i].split() or [""]
            toks[data.draw(st.integers(0, len(toks) - 1))] = data.draw(st.sampled_from(JUNK))
            lines[i] = " ".join(toks)
        else:
            text = "\n".join(lines)
            lines = text[:data.draw(st.integers(0, len(text)))].split("\n")
    p = tmp_path_factory.mktemp("fuzz") / "f.bvh"
    p.write_text("\n".join(lines) + "\n")
    try:
        clip = read_bvh(p)
    except InputError:
        return
    assert np.all(np.isfinite(clip.rotations)) and np.all(np.isfinite(clip.translations))
