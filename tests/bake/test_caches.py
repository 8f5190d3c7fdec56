"""Bake caches: npz / USD / pc2 round trips, exact PC2 header, NaN and failed writes leave no file."""
from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest

import jiggle.sim.bake.caches as caches
from jiggle.rig.base.errors import InputError
from jiggle.sim.bake.caches import BakeData, read_npz, read_pc2, write_npz, write_pc2, write_usd

T, FPS = 4, 30.0
# a tetrahedron, outward faces
TET = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int32)
MUSCLE_FACES = np.array([[0, 1, 2], [1, 3, 2]], np.int32)  # a stand-in loft on P = 4 points


def make_data(**change) -> dict:
    rng = np.random.default_rng(0)
    t = np.arange(T) / FPS
    static = TET[None] + 0.1 * t[:, None, None]
    final = static + 0.01 * rng.standard_normal((T, 4, 3))
    world = np.tile(np.eye(4, dtype=np.float32), (T, 3, 1, 1))
    world[:, :, :3, 3] = rng.standard_normal((T, 3, 3))
    cvs = rng.standard_normal((T, 80, 3))
    values = dict(skin_static=static, skin_final=final, faces=TET_FACES, fps=FPS, times=t + 0.5,
                  joint_names=("Hips", "LeftUpLeg", "LeftLeg"), joint_world=world,
                  muscle_names=("biceps_l", "belly fat"), muscle_cvs_static=cvs,
                  muscle_cvs_dynamic=cvs + 0.01, muscle_cv_offsets=[0, 40, 80],
                  muscle_faces=MUSCLE_FACES,
                  params=json.dumps({"jiggle": {"substeps": 4, "damping": 0.3}}))
    values.update(change)
    return values


def muscle_points():
    return np.random.default_rng(1).standard_normal((T, 2, 4, 3)).astype(np.float32)


def leftovers(folder) -> list[str]:
    return sorted(os.listdir(folder))


def test_npz_round_trip(tmp_path):
    data = BakeData(**make_data())
    path = tmp_path / "bake.npz"
    write_npz(data, path)
    back = read_npz(path)
    for name in caches.NPZ_KEYS:
        a, b = getattr(data, name), getattr(back, name)
        if isinstance(a, np.ndarray):
            assert a.dtype == b.dtype and np.array_equal(a, b), name
        else:
            assert a == b, name
    assert back.skin_final.dtype == np.float32 and back.faces.dtype == np.int32
    assert not back.skin_final.flags.writeable
    with np.load(path, allow_pickle=False) as npz:  # the documented layout, no pickles
        assert str(npz["format"]) == "jiggle.bake/1"
        assert npz["joint_world"].shape == (T, 3, 4, 4)
    assert leftovers(tmp_path) == ["bake.npz"]


def test_npz_without_suffix_keeps_its_name(tmp_path):
    write_npz(BakeData(**make_data()), tmp_path / "bake.cache")
    assert leftovers(tmp_path) == ["bake.cache"]
    assert read_npz(tmp_path / "bake.cache").num_frames == T


def test_read_npz_errors_name_file_and_key(tmp_path):
    path = tmp_path / "bad.npz"
    values = {k: v for k, v in make_data().items() if k != "muscle_faces"}
    np.savez(path, format=np.array("jiggle.bake/1"), **{k: np.asarray(v) for k, v in values.items()})
    with pytest.raises(InputError, match="muscle_faces") as e:
        read_npz(path)
    assert e.value.path == str(path) and e.value.field == "muscle_faces"
    np.savez(path, format=np.array("other/2"))
    with pytest.raises(InputError, match="format.*other/2"):
        read_npz(path)
    path.write_bytes(b"not a zip")
    with pytest.raises(InputError, match="bad.npz"):
        read_npz(path)


@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_usd_read_back(tmp_path, suffix):
    from pxr import Usd, UsdGeom

    data = BakeData(**make_data())
    mp = muscle_points()
    path = tmp_path / f"bake{suffix}"
    write_usd(data, path, muscle_points=mp)
    assert leftovers(tmp_path) == [path.name]
    head = path.read_bytes()[:8]
    assert head.startswith(b"PXR-USDC") if suffix == ".usdc" else head.startswith(b"#usda")
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == FPS
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, T - 1)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/jiggle"
    assert json.loads(stage.GetRootLayer().customLayerData["jiggle:params"]) == json.loads(data.params)
    for name in ("skin_static", "skin_final"):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(f"/jiggle/{name}"))
        assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
        assert np.array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()), TET_FACES.ravel())
        assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * 4
        assert mesh.GetPointsAttr().GetTimeSamples() == list(range(T))
        for k in range(T):
            pts = np.array(mesh.GetPointsAttr().Get(k), np.float32)
            assert np.array_equal(pts, getattr(data, name)[k])  # float32 in, float32 out
            n = np.array(mesh.GetNormalsAttr().Get(k))
            np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-6)
    # the tetrahedron's corner 3 = (0, 0, 1) at frame 0 of skin_static: its normal leans outward
    n0 = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/jiggle/skin_static")).GetNormalsAttr().Get(0))
    assert n0[3] @ (TET[3] - TET.mean(0)) > 0
    for m, ident in enumerate(("biceps_l", "belly_fat")):
        prim = stage.GetPrimAtPath(f"/jiggle/muscles/{ident}")
        assert prim.GetAttribute("jiggle:name").Get() == data.muscle_names[m]
        pts_attr = UsdGeom.Mesh(prim).GetPointsAttr()
        for k in range(T):
            assert np.array_equal(np.array(pts_attr.Get(k), np.float32), mp[k, m])


def test_usd_suffix_and_flag(tmp_path):
    data = BakeData(**make_data())
    write_usd(data, tmp_path / "a.usd", usda=True)
    assert (tmp_path / "a.usd").read_bytes().startswith(b"#usda")
    write_usd(data, tmp_path / "b.usd")
    assert (tmp_path / "b.usd").read_bytes().startswith(b"PXR-USDC")
    with pytest.raises(InputError, match="contradicts"):
        write_usd(data, tmp_path / "c.usdc", usda=True)
    with pytest.raises(InputError, match="suffix"):
        write_usd(data, tmp_path / "d.abc")
    assert leftovers(tmp_path) == ["a.usd", "b.usd"]


def test_pc2_round_trip_and_header(tmp_path):
    pts = BakeData(**make_data()).skin_final
    path = tmp_path / "skin.pc2"
    write_pc2(pts, path, fps=FPS, start_time=0.5)
    raw = path.read_bytes()
    assert raw[:32] == (b"POINTCACHE2\0" + struct.pack("<i", 1) + struct.pack("<i", 4)
                        + struct.pack("<f", 15.0) + struct.pack("<f", 1.0) + struct.pack("<i", T))
    assert len(raw) == 32 + T * 4 * 3 * 4
    back = read_pc2(path)
    assert np.array_equal(back.points, pts) and back.points.dtype == np.float32
    assert (back.start_frame, back.sample_rate) == (15.0, 1.0)
    path.write_bytes(raw[:-4])
    with pytest.raises(InputError, match="skin.pc2"):
        read_pc2(path)


def test_nan_in_skin_final_names_key_and_frame_and_writes_nothing(tmp_path):
    final = np.array(make_data()["skin_final"])
    final[2, 1, 0] = np.nan
    with pytest.raises(InputError, match=r"skin_final.*frame 2, vertex 1") as e:
        BakeData(**make_data(skin_final=final))
    assert e.value.field == "skin_final"
    with pytest.raises(InputError, match=r"points.*frame 2, vertex 1"):
        write_pc2(final, tmp_path / "skin.pc2", fps=FPS)
    bad_muscles = muscle_points()
    bad_muscles[3, 1, 2, 2] = np.inf
    with pytest.raises(InputError, match=r"muscle_points.*frame 3"):
        write_usd(BakeData(**make_data()), tmp_path / "bake.usdc", muscle_points=bad_muscles)
    assert leftovers(tmp_path) == []


def test_bad_shapes_and_times(tmp_path):
    with pytest.raises(InputError, match="times.*frame 2"):
        BakeData(**make_data(times=[0.0, 0.1, 0.1, 0.2]))
    with pytest.raises(InputError, match="fps"):
        BakeData(**make_data(fps=0))
    with pytest.raises(InputError, match="muscle_cvs_dynamic"):
        BakeData(**make_data(muscle_cvs_dynamic=np.zeros((T, 79, 3))))
    with pytest.raises(InputError, match="faces"):
        BakeData(**make_data(faces=[[0, 1, 4]]))
    with pytest.raises(InputError, match="params"):
        BakeData(**make_data(params="{not json"))


def test_unwritable_folder_names_the_path(tmp_path):
    (tmp_path / "file").write_text("a file where a folder should be")
    target = tmp_path / "file" / "bake.npz"  # works even as root, unlike chmod
    data = BakeData(**make_data())
    for write in (lambda p: write_npz(data, p), lambda p: write_usd(data, p.with_suffix(".usdc")),
                  lambda p: write_pc2(data.skin_final, p.with_suffix(".pc2"), FPS)):
        with pytest.raises(InputError, match="cannot write") as e:
            write(target)
        assert e.value.path.startswith(str(tmp_path / "file" / "bake."))
    assert leftovers(tmp_path) == ["file"]


def test_interrupted_writes_leave_no_file(tmp_path, monkeypatch):
    data = BakeData(**make_data())

    def half_npz(fh, **arrays):
        fh.write(b"PK\x03\x04 half a zip")
        raise KeyboardInterrupt

    def half_frames(fh, p):
        fh.write(p[0].tobytes())
        raise KeyboardInterrupt

    def half_save(layer):
        raise KeyboardInterrupt

    monkeypatch.setattr(caches.np, "savez_compressed", half_npz)
    monkeypatch.setattr(caches, "_write_frames", half_frames)
    monkeypatch.setattr(caches, "_save_layer", half_save)
    with pytest.raises(KeyboardInterrupt):
        write_npz(data, tmp_path / "bake.npz")
    with pytest.raises(KeyboardInterrupt):
        write_pc2(data.skin_final, tmp_path / "skin.pc2", FPS)
    with pytest.raises(KeyboardInterrupt):
        write_usd(data, tmp_path / "bake.usdc")
    assert leftovers(tmp_path) == []


def test_caches_filled_chunk_by_chunk_equal_whole_ones(tmp_path):
    """A bake's writers: an npz laid out up front and filled in blocks of 2 + 1 + 1 frames (stopped after
    the first block and reopened with its progress, as a resumed bake does) reads back equal to one
    written whole, passes zip's CRC test; a USD appended block by block equals one written whole; a
    block that does not go on from the frames written, or a member left short, is refused."""
    import zipfile

    from pxr import Usd, UsdGeom
    data = BakeData(**make_data())
    whole = caches.npz_arrays(data)
    frame_keys = [k for k in caches.FRAME_KEYS if k != "times" and getattr(data, k) is not None]
    members = {k: ((getattr(data, k).shape, np.float32) if k in frame_keys else v) for k, v in whole.items()}
    path = str(tmp_path / "filled.npz")
    npz = caches.NpzInPlace(path, members)
    for k in frame_keys:
        npz.write(k, 0, getattr(data, k)[:2])
    crcs, frames = npz.progress()
    npz.close()
    npz = caches.NpzInPlace(path, members, crcs, frames)
    with pytest.raises(InputError, match="does not continue"):
        npz.write("skin_final", 3, data.skin_final[3:])
    for a, b in ((2, 3), (3, 4)):
        for k in frame_keys:
            npz.write(k, a, getattr(data, k)[a:b])
    npz.finish()
    assert zipfile.ZipFile(path).testzip() is None
    back = read_npz(path)
    for name in caches.NPZ_KEYS:
        a, b = getattr(data, name), getattr(back, name)
        assert (np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b), name
    short = caches.NpzInPlace(str(tmp_path / "short.npz"), members)
    with pytest.raises(InputError, match="holds 0 of 4 frames"):
        short.finish()
    short.close()

    mp = muscle_points()
    usd = caches.UsdAppender(str(tmp_path / "blocks.usdc"), data, T, mp.shape, "usdc")
    for a, b in ((0, 2), (2, 3), (3, 4)):
        usd.append(a, {"skin_static": data.skin_static[a:b], "skin_final": data.skin_final[a:b], "muscles": mp[a:b]})
    usd.finish()
    write_usd(data, tmp_path / "whole.usdc", muscle_points=mp)
    s1, s2 = Usd.Stage.Open(str(tmp_path / "blocks.usdc")), Usd.Stage.Open(str(tmp_path / "whole.usdc"))
    for prim in ("/jiggle/skin_static", "/jiggle/skin_final", "/jiggle/muscles/biceps_l", "/jiggle/muscles/belly_fat"):
        m1, m2 = UsdGeom.Mesh(s1.GetPrimAtPath(prim)), UsdGeom.Mesh(s2.GetPrimAtPath(prim))
        for k in range(T):
            for get in (UsdGeom.Mesh.GetPointsAttr, UsdGeom.Mesh.GetNormalsAttr, UsdGeom.Mesh.GetExtentAttr):
                assert np.array_equal(np.array(get(m1).Get(k)), np.array(get(m2).Get(k))), (prim, k)
    assert np.array_equal(np.array(UsdGeom.Mesh(s1.GetPrimAtPath("/jiggle/skin_final")).GetPointsAttr().Get(3)),
                          data.skin_final[3])


def test_interrupted_overwrite_keeps_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "skin.pc2"
    old = BakeData(**make_data()).skin_static
    write_pc2(old, path, FPS)
    before = path.read_bytes()

    def fail(fh, p):
        fh.write(b"\0" * 10)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(caches, "_write_frames", fail)
    with pytest.raises(InputError, match="No space left") as e:
        write_pc2(old + 1, path, FPS)
    assert e.value.path == str(path)
    assert path.read_bytes() == before and leftovers(tmp_path) == ["skin.pc2"]


def test_skin_parts_round_trip_and_name_usd_subsets(tmp_path):
    """A skin merged from two meshes keeps their names: npz part_names/part_offsets, and one face
    GeomSubset per part on both USD skin meshes (a face goes with its first vertex's part)."""
    from pxr import Usd, UsdGeom
    data = BakeData(**make_data(part_names=("Body mesh", "eyes"), part_offsets=[0, 1, 4]))
    write_npz(data, tmp_path / "bake.npz")
    back = read_npz(tmp_path / "bake.npz")
    assert back.part_names == ("Body mesh", "eyes") and back.part_offsets.tolist() == [0, 1, 4]
    write_usd(data, tmp_path / "bake.usda")
    stage = Usd.Stage.Open(str(tmp_path / "bake.usda"))
    for name in ("skin_static", "skin_final"):
        subsets = UsdGeom.Subset.GetGeomSubsets(UsdGeom.Imageable(stage.GetPrimAtPath(f"/jiggle/{name}")),
                                                UsdGeom.Tokens.face, "part")
        got = {s.GetPrim().GetAttribute("jiggle:name").Get(): sorted(s.GetIndicesAttr().Get()) for s in subsets}
        assert got == {"Body mesh": [0, 1, 2], "eyes": [3]}
    # parts must cover the vertices in order, names and offsets together
    for bad, field in ((dict(part_names=("a", "b"), part_offsets=[0, 2, 3]), "part_offsets"),
                       (dict(part_names=("a", "b"), part_offsets=[0, 3, 2, 4]), "part_offsets"),
                       (dict(part_names=("a",)), "part_names")):
        with pytest.raises(InputError) as e:
            BakeData(**make_data(**bad))
        assert e.value.field == field
    # a bake without parts writes neither key
    write_npz(BakeData(**make_data()), tmp_path / "plain.npz")
    with np.load(tmp_path / "plain.npz") as npz:
        assert "part_names" not in npz.files
