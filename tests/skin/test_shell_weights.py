"""Painted shell deformer weights (rig/skin/shell/weights.py): the weight file's round trip, matching columns
to the rig's muscles by name, an error naming the file and the key or muscle for each kind of bad
file, atomic writes, and the gather of w_i for CSR (vertex, muscle) pairs against a loop."""
from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from jiggle.rig.base.errors import InputError, JiggleWarning
from jiggle.rig.skin.shell.weights import FORMAT, KEYS, find_weights, load_weights, pair_weights, save_weights, sidecar_path

NAMES = ["left_biceps", "left_triceps", "belly_fat"]


def table(v=7, m=3, seed=0) -> np.ndarray:
    return np.random.default_rng(seed).random((v, m)).astype(np.float32)


def write_raw(path, **arrays):
    """An .npz with exactly these arrays (to build broken files by hand)."""
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def good_arrays(w=None, names=NAMES):
    w = table() if w is None else w
    return {"format": np.array(FORMAT), "muscle_names": np.array(names), "weights": w,
            "num_vertices": np.array(w.shape[0])}


def load_quiet(path, names=NAMES, v=7):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning expected when the names match
        return load_weights(path, names, v)


# ------------------------------------------------------------------------------- round trip and names
def test_round_trip(tmp_path):
    w = table().astype(np.float64)
    w[0, 0], w[1, 2] = 0.0, 1.0  # both ends of the range are valid
    path = save_weights(tmp_path / "man.shell_weights.npz", NAMES, w)
    assert path == tmp_path / "man.shell_weights.npz"
    out = load_quiet(path)
    assert out.dtype == np.float32 and out.shape == (7, 3)
    np.testing.assert_array_equal(out, w.astype(np.float32))
    with np.load(path, allow_pickle=False) as d:  # the documented layout
        assert sorted(d.files) == sorted(KEYS)
        assert str(d["format"]) == FORMAT and d["muscle_names"].dtype.kind == "U"
        assert d["muscle_names"].tolist() == NAMES and d["weights"].dtype == np.float32
        assert int(d["num_vertices"]) == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ["man.shell_weights.npz"]  # no temp file left
    assert path.stat().st_mode & 0o777 == 0o644  # not the temporary file's private 0600


def test_columns_follow_the_rig_order(tmp_path):
    w = table()
    path = save_weights(tmp_path / "w.npz", NAMES, w)
    order = [2, 0, 1]
    out = load_quiet(path, [NAMES[i] for i in order])
    np.testing.assert_array_equal(out, w[:, order])


def test_extra_and_missing_muscles_warn(tmp_path):
    w = table()
    path = save_weights(tmp_path / "w.npz", NAMES, w)
    rig = ["belly_fat", "right_biceps", "left_biceps"]
    with pytest.warns(JiggleWarning) as record:
        out = load_weights(path, rig, 7)
    messages = [str(r.message) for r in record]
    assert len(messages) == 2
    assert any("ignoring" in s and "left_triceps" in s and str(path) in s for s in messages), messages
    assert any("right_biceps" in s and "weight 1" in s and "left_triceps" not in s for s in messages), messages
    np.testing.assert_array_equal(out[:, 0], w[:, 2])
    np.testing.assert_array_equal(out[:, 1], np.ones(7, np.float32))
    np.testing.assert_array_equal(out[:, 2], w[:, 0])


def test_sidecar_path_and_find(tmp_path):
    character = tmp_path / "chars" / "CesiumMan.glb"
    assert sidecar_path(character) == tmp_path / "chars" / "CesiumMan.shell_weights.npz"
    assert sidecar_path("body.toml") == sidecar_path("body.glb")
    character.parent.mkdir()
    assert find_weights(character) is None
    save_weights(sidecar_path(character), NAMES, table())
    assert find_weights(character) == sidecar_path(character)


# ------------------------------------------------------------------------------- errors
def test_missing_and_not_npz(tmp_path):
    with pytest.raises(InputError, match="shell weight file not found") as e:
        load_weights(tmp_path / "none.npz", NAMES, 7)
    assert e.value.path == str(tmp_path / "none.npz")
    text = tmp_path / "text.npz"
    text.write_text("weights: all ones\n")
    with pytest.raises(InputError, match="not a readable .npz") as e:
        load_weights(text, NAMES, 7)
    assert e.value.path == str(text)
    single = tmp_path / "single.npz"
    with open(single, "wb") as fh:
        np.save(fh, table())
    with pytest.raises(InputError, match=r"not an \.npz archive \(a single \.npy array\)"):
        load_weights(single, NAMES, 7)
    truncated = tmp_path / "truncated.npz"
    save_weights(truncated, NAMES, table())
    truncated.write_bytes(truncated.read_bytes()[:40])
    with pytest.raises(InputError, match="not a readable .npz") as e:
        load_weights(truncated, NAMES, 7)
    assert e.value.path == str(truncated)


@pytest.mark.parametrize("key", KEYS)
def test_missing_key(tmp_path, key):
    arrays = good_arrays()
    del arrays[key]
    path = write_raw(tmp_path / "w.npz", **arrays)
    with pytest.raises(InputError) as e:
        load_weights(path, NAMES, 7)
    assert e.value.field == key and e.value.path == str(path)
    assert f"missing key(s) {key!r}" in e.value.message


def test_wrong_format_tag(tmp_path):
    for tag in (np.array("jiggle.shell_weights/2"), np.array(["jiggle.shell_weights/1"]), np.array(1)):
        path = write_raw(tmp_path / "w.npz", **{**good_arrays(), "format": tag})
        with pytest.raises(InputError, match=r"format tag .*; expected 'jiggle\.shell_weights/1'") as e:
            load_weights(path, NAMES, 7)
        assert e.value.field == "format" and e.value.path == str(path)


def test_vertex_count_mismatch(tmp_path):
    path = save_weights(tmp_path / "w.npz", NAMES, table(v=7))
    with pytest.raises(InputError) as e:
        load_weights(path, NAMES, 8)
    assert e.value.field == "num_vertices" and e.value.path == str(path)
    assert "mesh of 7 vertices; the character has 8" in e.value.message
    # the file's own num_vertices disagreeing with its table
    path = write_raw(tmp_path / "x.npz", **{**good_arrays(), "num_vertices": np.array(6)})
    with pytest.raises(InputError, match=r"expected shape \(6, 3\).*got \(7, 3\)") as e:
        load_weights(path, NAMES, 7)
    assert e.value.field == "weights"


def test_malformed_names_and_table(tmp_path):
    path = write_raw(tmp_path / "w.npz", **good_arrays(names=["a", "b", "a"]))
    with pytest.raises(InputError, match="muscle name 'a' is given twice") as e:
        load_weights(path, NAMES, 7)
    assert e.value.field == "muscle_names" and e.value.path == str(path)
    path = write_raw(tmp_path / "w.npz", **{**good_arrays(), "muscle_names": np.arange(3)})
    with pytest.raises(InputError, match="expected a 1-D array of strings") as e:
        load_weights(path, NAMES, 7)
    path = write_raw(tmp_path / "w.npz", **{**good_arrays(), "weights": table(m=2)})
    with pytest.raises(InputError, match=r"expected shape \(7, 3\)") as e:
        load_weights(path, NAMES, 7)
    path = write_raw(tmp_path / "w.npz", **{**good_arrays(), "num_vertices": np.array(7.0)})
    with pytest.raises(InputError, match="expected an integer") as e:
        load_weights(path, NAMES, 7)
    assert e.value.field == "num_vertices"


@pytest.mark.parametrize("bad", [np.nan, -0.01, 1.5, np.inf])
def test_bad_value_names_muscle_and_vertex(tmp_path, bad):
    w = table()
    w[4, 1] = bad
    w[5, 0] = bad  # a later vertex: the message names the first one
    path = write_raw(tmp_path / "w.npz", **good_arrays(w))
    with pytest.raises(InputError) as e:
        load_weights(path, NAMES, 7)
    assert e.value.field == "weights.left_triceps" and e.value.path == str(path)
    assert e.value.message.startswith("muscle 'left_triceps', vertex 4: weight")
    assert "expected values in [0, 1] (2 bad value(s) in all)" in e.value.message


def test_save_checks_its_input(tmp_path):
    with pytest.raises(InputError, match=r"expected weights of shape \(V, 3\)"):
        save_weights(tmp_path / "w.npz", NAMES, table(m=2))
    with pytest.raises(InputError, match="given twice"):
        save_weights(tmp_path / "w.npz", ["a", "a"], table(m=2))
    w = table()
    w[2, 2] = 1.25
    with pytest.raises(InputError, match="muscle 'belly_fat', vertex 2"):
        save_weights(tmp_path / "w.npz", NAMES, w)
    with pytest.raises(InputError, match="muscle names must be non-empty strings"):
        load_weights(tmp_path / "w.npz", ["a", 3], 7)
    assert not list(tmp_path.iterdir())


# ------------------------------------------------------------------------------- atomic writes
def test_failed_write_keeps_the_old_file(tmp_path, monkeypatch):
    path = save_weights(tmp_path / "w.npz", NAMES, table(seed=1))
    before = path.read_bytes()

    def half_then_fail(fh, **arrays):
        fh.write(b"PK\x03\x04 half an archive")  # the start of a zip, as a real write would leave it
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", half_then_fail)
    with pytest.raises(OSError, match="No space left"):
        save_weights(path, NAMES, table(seed=2))
    with pytest.raises(OSError):
        save_weights(tmp_path / "new.npz", NAMES, table(seed=2))
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.npz"]  # no temp file, no half "new.npz"
    assert path.read_bytes() == before
    np.testing.assert_array_equal(load_quiet(path), table(seed=1))


def test_overwrite_keeps_mode(tmp_path):
    path = save_weights(tmp_path / "w.npz", NAMES, table(seed=1))
    os.chmod(path, 0o600)
    save_weights(path, NAMES, table(seed=2))
    assert path.stat().st_mode & 0o777 == 0o600
    np.testing.assert_array_equal(load_quiet(path), table(seed=2))


# ------------------------------------------------------------------------------- pair gather
def test_pair_weights_gather():
    rng = np.random.default_rng(3)
    v, m = 50, 6
    w = rng.random((v, m)).astype(np.float32)
    keep = rng.random((v, m)) < 0.4  # culled pairs: CSR by vertex, ascending muscle
    keep[7] = False  # a vertex without pairs
    counts = keep.sum(axis=1)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    muscle = np.nonzero(keep)[1].astype(np.int32)
    out = pair_weights(w, offsets, muscle)
    # reference: the loop the CSR layout describes
    ref = [w[i, muscle[k]] for i in range(v) for k in range(offsets[i], offsets[i + 1])]
    assert out.dtype == np.float32 and out.shape == (int(counts.sum()),)
    np.testing.assert_array_equal(out, np.array(ref, np.float32))
    assert pair_weights(np.ones((3, 2)), np.zeros(4, np.int32), np.zeros(0, np.int32)).shape == (0,)


def test_pair_weights_rejects_bad_layout():
    w = np.ones((3, 2), np.float32)
    with pytest.raises(ValueError, match="pair_offsets"):
        pair_weights(w, np.array([0, 1, 2]), np.array([0, 1]))  # V offsets, not V + 1
    with pytest.raises(ValueError, match="non-decreasing"):
        pair_weights(w, np.array([0, 2, 1, 2]), np.array([0, 1]))
    with pytest.raises(ValueError, match=r"muscle indices in \[0, 2\)"):
        pair_weights(w, np.array([0, 1, 1, 2]), np.array([0, 2]))
