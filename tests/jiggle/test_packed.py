"""Many bakes' particles in one model (sim/jiggle/packed.py): three different bakes (CesiumMan on two CMU clips and
the generated demo body) stepped chunk by chunk as one pack give each bake's own trajectories and states, bit for
bit; packing and unpacking keep every particle's data; bakes whose chunks differ run alone."""
import os
from pathlib import Path

import numpy as np
import pytest

from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.packed import PackedBakes, pack_models, pack_tracks
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.simulate import run
from jiggle.sim.jiggle.solver import ParticleSolver

ROOT = Path(__file__).resolve().parents[2]
ASSETS = Path(os.environ.get("JIGGLE_ASSETS", ROOT.parent / "shared" / "assets"))
CESIUM = ASSETS / "characters" / "CesiumMan.glb"
CLIPS = [ASSETS / "mocap" / "cmu_bvh" / "02_03.bvh", ASSETS / "mocap" / "cmu_bvh" / "05_02.bvh"]


def small_models():
    """Two different small models: 2 and 3 chains of 4 particles with springs, different masses and goals."""
    out = []
    rng = np.random.default_rng(3)
    for chains, k in ((2, 40.0), (3, 90.0)):
        b = ParticleBuilder()
        for c in range(chains):
            b.begin_group(f"m{c}")
            base = b.num_particles
            b.add_particles(rng.normal(0, 0.05, (4, 3)), rng.uniform(0.01, 0.05, 4), [k, k, np.inf, k],
                            rng.uniform(1, 3, 4), 0.1, 0.02)
            b.add_springs([[base, base + 1], [base + 1, base + 2], [base + 2, base + 3]], 2.0, 0.05)
        out.append(b.finalize())
    return out


def test_pack_and_unpack_keep_every_particle():
    """pack_models: particles, springs (indices shifted), muscles and the batch index; unpack inverts pack."""
    a, b = small_models()
    pm = pack_models([a, b], ["a", "b"])
    assert pm.model.num_particles == a.num_particles + b.num_particles
    assert pm.model.num_springs == a.num_springs + b.num_springs
    np.testing.assert_array_equal(pm.offsets, [0, 8, 20])
    np.testing.assert_array_equal(pm.batch, np.repeat([0, 1], [8, 12]))
    np.testing.assert_array_equal(pm.wp_batch.numpy(), pm.batch)
    np.testing.assert_array_equal(pm.model.springs, np.concatenate([a.springs, b.springs + 8]))
    assert pm.model.group_of(9) == "b/m0"
    for name in ("mass", "goal_k", "goal_c", "drag", "reach", "rest"):
        for part, m in zip(pm.unpack(getattr(pm.model, name)), (a, b)):
            np.testing.assert_array_equal(part, getattr(m, name))
    for name in ("wp_inv_mass", "wp_adj_k", "wp_adj_c"):
        np.testing.assert_array_equal(getattr(pm.model, name).numpy(),
                                      np.concatenate([getattr(a, name).numpy(), getattr(b, name).numpy()]))


def test_small_models_packed_equal_each_alone():
    """Two small models on goals that move differently, started on their goals, stepped in chunks: the pack gives
    each model's positions and end states bit for bit (the tissue law engaged: reach 2 cm, goals jerked 3 cm)."""
    models = small_models()
    knots = np.arange(0, 1.0 + 1e-9, 1 / 60)
    tracks = []
    for i, m in enumerate(models):
        wobble = 0.03 * np.sign(np.sin(2 * np.pi * (3 + i) * knots))[:, None, None] * np.array([1.0, 0.5 * i, 0.2])
        tracks.append(build_track(knots, m.rest[None] + wobble, cuts=np.zeros(len(knots) - 1, bool)))
    times = np.arange(0, 1.0 + 1e-9, 1 / 30)
    packed = PackedBakes(models)
    alone = [ParticleSolver(m) for m in models]
    states, pstates = [None, None], [None, None]
    for f0 in range(0, len(times), 7):
        t = times[max(f0 - 1, 0):f0 + 7]
        got = packed.simulate(tracks, [t, t], 4, pstates)
        for b, m in enumerate(models):
            x, states[b] = run(m, tracks[b], t, 4, 0.0, alone[b], start=states[b], return_state=True)
            np.testing.assert_array_equal(got[b][0], x)
            np.testing.assert_array_equal(got[b][1][0], states[b][0])
            np.testing.assert_array_equal(got[b][1][1], states[b][1])
            pstates[b] = got[b][1]
    assert packed.packed_runs == -(-len(times) // 7) and packed.alone_runs == 0


def _setups():
    from jiggle.sim.bake.setup import BakeRequest, prepare
    if not (CESIUM.exists() and all(c.exists() for c in CLIPS)):
        pytest.skip(f"the shared assets ({CESIUM}, {', '.join(c.name for c in CLIPS)}) are not here")
    common = {"fps": 30, "frames": 40, "chunk": 16, "collisions": False, "preroll": 0.0, "loop": "off",
              "formats": ("npz",)}
    reqs = [BakeRequest(clip=str(c), character=str(CESIUM), **common) for c in CLIPS]
    reqs.append(BakeRequest(scene=str(ROOT / "scenes" / "default.toml"), body={"resolution": 3000}, **common))
    return [prepare(r) for r in reqs]


def chunk_track(setup, c):
    """Bake chunk c's goal track and output times, as sim/bake/baker.py's Baker.chunk makes them."""
    from jiggle.sim.bake.baker import MARGIN, chunk_frames
    from jiggle.sim.jiggle.simulate import TIME_EPS, goals
    s = setup
    f0, f1 = chunk_frames(s, c)
    a = max(f0 - 1, 0)
    ka = max(0, int(np.searchsorted(s.knots, s.times[a] - TIME_EPS)) - MARGIN)
    kb = min(len(s.knots), int(np.searchsorted(s.knots, s.times[f1 - 1] + TIME_EPS, side="right")) + MARGIN)
    kt = s.knots[ka:kb]
    static = s.rig.static(np.asarray(s.world_at(kt), dtype=np.float64), device=s.settings.device)
    return goals(s.rig, kt, static.cvs, s.settings), s.times[a:f1]


def test_three_bakes_packed_equal_each_bake_alone():
    """CesiumMan on 02_03 and on 05_02 (one model, other goals) and the generated demo body (another body: other rest
    CVs, masses, springs), 40 frames in chunks of 16: each chunk of the three stepped as one pack equals each bake's own
    run of that chunk (sim.jiggle.simulate.run, as the bake calls it), positions and end states bit for bit, chunk
    after chunk (each going on from its own end state); the three run as one pack."""
    from jiggle.sim.jiggle.particles import muscle_model
    setups = _setups()
    models = [muscle_model(s.rig, list(s.jiggles), "cpu", gravity=s.settings.gravity) for s in setups]
    assert not np.array_equal(models[0].rest, models[2].rest)                       # other bodies, other springs
    substeps = {s.settings.substeps for s in setups}
    assert len(substeps) == 1
    substeps = substeps.pop()
    packed = PackedBakes(models, ["cesium_02_03", "cesium_05_02", "demo"])
    alone = [ParticleSolver(m) for m in models]
    states, pstates = [None] * 3, [None] * 3
    chunks = -(-len(setups[0].times) // setups[0].chunk)
    for c in range(chunks):
        tracks, times = zip(*(chunk_track(s, c) for s in setups))
        got = packed.simulate(list(tracks), list(times), substeps, pstates)
        for b, m in enumerate(models):
            x, states[b] = run(m, tracks[b], times[b], substeps, 0.0, alone[b], start=states[b], return_state=True)
            np.testing.assert_array_equal(got[b][0], x)
            np.testing.assert_array_equal(got[b][1][0], states[b][0])
            np.testing.assert_array_equal(got[b][1][1], states[b][1])
            pstates[b] = got[b][1]
        assert np.abs(x[-1] - tracks[-1].sample(times[-1][-1])[0]).max() > 1e-5      # the demo body jiggles
    assert packed.packed_runs >= chunks - 1            # every chunk of the three as one pack
    assert (0, 1, 2) in packed._packs


def test_a_bake_whose_chunk_differs_runs_alone():
    """A bake with other output times (a shorter last chunk) is not packed with the rest: it runs alone, its own."""
    models = small_models()
    knots = np.arange(0, 1.0 + 1e-9, 1 / 60)
    tracks = [build_track(knots, m.rest[None] + 0.01 * knots[:, None, None], cuts=np.zeros(len(knots) - 1, bool))
              for m in models]
    packed = PackedBakes(models)
    t0, t1 = np.arange(0, 0.5, 1 / 30), np.arange(0, 0.3, 1 / 30)
    got = packed.simulate(tracks, [t0, t1], 4, [None, None])
    assert packed.alone_runs == 2 and packed.packed_runs == 0
    np.testing.assert_array_equal(got[1][0], run(models[1], tracks[1], t1, 4, 0.0, ParticleSolver(models[1])))
    with pytest.raises(Exception, match="same knots"):
        pack_tracks([tracks[0], build_track(knots[:-1], tracks[1].pos[:-1])])
