"""The chunk graph (sim/jiggle/graph.py): a chunk's particle stepping as one device program, captured once per
chunk shape and replayed. On the CPU: the program (the GPU's launches: a launch per step) equals the plain path bit
for bit over a chunked run with capsules, a floor, tissue contacts, the tissue law and a cut; nothing in it reads the
device back; two chunks of one shape give one signature; and Warp's CPU graph (ScopedCapture / capture_launch on
the CPU) replays it to the same bits. On a CUDA device (skipped here when there is none) the captured graph against
the plain launches."""
from dataclasses import replace

import numpy as np
import pytest
import warp as wp

from jiggle.rig.character.capsules import BoneCapsules
from jiggle.sim.jiggle.colliders import ColliderModel
from jiggle.sim.jiggle.goal_track import build_track
from jiggle.sim.jiggle.graph import ChunkGraph, GraphArrays, signature
from jiggle.sim.jiggle.params import MuscleJiggle, section_goals
from jiggle.sim.jiggle.particles import ParticleBuilder
from jiggle.sim.jiggle.simulate import run
from jiggle.sim.jiggle.solver import ParticleSolver
from jiggle.sim.jiggle.tissue_contacts import TissueContactModel

JIGGLE = MuscleJiggle(name="A", frequency_hz=3.0, damping_ratio=0.2, goal=section_goals(0.3, 0.15), density=900.0,
                      spring_frequency_hz=6.0, spring_damping_ratio=0.3, max_offset=0.012)
"""Pads with a reach of 12 mm: the press drives them past half of it, so the tissue law's substeps are taken."""


def fat_pad(centre, radius=0.03, width=0.12):
    """(40, 3) CVs: 5 rings of 8 about the y axis around `centre` (as tests/jiggle/test_tissue_contacts.py)."""
    ys = np.linspace(-0.5, 0.5, 5) * width
    a = 2 * np.pi * np.arange(8) / 8
    ring = np.stack([np.cos(a) * radius, np.zeros(8), np.sin(a) * radius], axis=1)
    return np.concatenate([ring + [0.0, y, 0.0] for y in ys]) + np.asarray(centre)


def press(device="cpu", cut_at=None):
    """Pads A (bone 0) and B (bone 1) slide 7 cm toward each other between 0.1 and 0.3 s, jerk up and down from
    0.35 s, over a capsule and a floor: capsule, floor and tissue contacts all hit. cut_at : a knot time where the
    goals jump 20 cm (a cut: glued through it, restarted after). (model, track, colliders, tissue)."""
    rest = np.concatenate([fat_pad([-0.08, 0.0, 0.0]), fat_pad([0.08, 0.0, 0.0])])
    b = ParticleBuilder()
    b.add_muscles(rest, np.full(2, 3e-4), [replace(JIGGLE, name=n) for n in "AB"])
    model = b.finalize(device, gravity=True)
    knots = np.arange(0, 1.2 + 1e-9, 1 / 120)
    s = np.clip((knots - 0.1) / 0.2, 0, 1)
    s = s * s * (3 - 2 * s)
    move = np.zeros((len(knots), len(rest), 3))
    move[:, :40, 0] = 0.07 * s[:, None]
    move[:, 40:, 0] = -0.07 * s[:, None]
    move[:, :, 2] += 0.03 * np.sign(np.sin(2 * np.pi * 4 * np.maximum(knots - 0.35, 0)))[:, None]
    cuts = np.zeros(len(knots) - 1, bool)
    if cut_at is not None:
        j = int(np.searchsorted(knots, cut_at))
        move[j:, :, 1] += 0.2
        cuts[j - 1] = True
    track = build_track(knots, rest[None] + move, cuts=cuts)
    caps = BoneCapsules(joint=np.zeros(1), child=np.full(1, -1), local=np.array([[[0.0, -0.1, -0.045],
                                                                                   [0.0, 0.1, -0.045]]]),
                        radius=np.array([0.02]), names=["c0"], parents=np.array([-1]))
    cm = ColliderModel.from_pairs(caps, np.ones((2, 1), bool), floor=-0.035, device=device)
    col = cm.on_track(knots, np.repeat(caps.local.reshape(1, 2, 3), len(knots), axis=0), cuts)
    tissue = TissueContactModel.build(rest, model.group_offsets, (0, 1), muscle_names=["A", "B"], device=device)
    return model, track, col, tissue


TIMES = np.arange(0, 1.2 + 1e-9, 1 / 30)
CHUNK = 8


def chunked(model, track, solver, colliders, tissue, times=TIMES, chunk=CHUNK):
    """A bake's particle stage: chunks of `chunk` frames, each going on from the state the one before ended in
    (sim/bake/baker.py). (positions (T, N, 3), records (T, N, 3), end state (x, v), the solver's hard stops)."""
    xs, recs, state = [], [], None
    stops = np.zeros(model.num_particles, np.int64)
    for f0 in range(0, len(times), chunk):
        a = max(f0 - 1, 0)
        f1 = min(f0 + chunk, len(times))
        sink = {}
        solver.stops.zero_()
        x, state = run(model, track, times[a:f1], 4, 0.0, solver, start=state, return_state=True,
                       colliders=colliders, contacts=sink, tissue=tissue)
        stops += solver.hard_stops()
        xs.append(x[1:] if f0 else x)
        recs.append(sink["records"][1:] if f0 else sink["records"])
    return np.concatenate(xs), np.concatenate(recs), state, stops


def graph_solver(model, capture: bool) -> ParticleSolver:
    solver = ParticleSolver(model)
    solver.stepwise = True                  # the GPU's launches: a launch per step, a thread per particle
    solver.graph = ChunkGraph(solver, capture=capture)
    return solver


def assert_same(a, b):
    for u, w in zip(a, b):
        for p, q in zip(u if isinstance(u, tuple) else (u,), w if isinstance(w, tuple) else (w,)):
            np.testing.assert_array_equal(p, q)


@pytest.mark.parametrize("with_tissue", [False, True])
def test_the_graph_path_equals_the_plain_path_bit_for_bit(with_tissue):
    """The press in chunks of 8 frames, with a cut (glue, then a restart on the device): positions, contact
    records, the end state and the hard stops of the chunk program (the GPU's launch per step, launched directly)
    and of the plain path (the CPU's one-launch runs, a state read back at each restart) are equal to the bit,
    with and without tissue contacts. The contacts and the tissue law act (records hit, particles past half their
    reach)."""
    model, track, col, tissue = press(cut_at=0.8)
    tissue = tissue if with_tissue else None
    plain = chunked(model, track, ParticleSolver(model), col, tissue)
    solver = graph_solver(model, capture=False)
    graphed = chunked(model, track, solver, col, tissue)
    assert_same(plain, graphed)
    assert solver.graph.direct == int(np.ceil(len(TIMES) / CHUNK)) and solver.graph.captures == 0
    hits = plain[1][..., 2]
    assert ((hits >= 0) & (hits < 2)).any()                            # capsule / floor
    if with_tissue:
        assert (hits >= 2).any()                                       # the other pad
    x, goal = plain[0], np.stack([track.sample(t)[0] for t in TIMES])
    reach = model.reach[None]
    assert (np.linalg.norm(x - goal, axis=2) > 0.5 * reach).any()      # the tissue law stiffens past half its reach


def test_a_chunk_program_reads_nothing_back(monkeypatch):
    """Inside a chunk's program (its operations launched) no device array is read to the host and nothing waits for
    the device: wp.array.numpy, wp.synchronize* and the device flags' host reads are counted and stay at zero while
    the operations of every chunk (tissue contacts on: a pass after every step) run; the reads are after it."""
    model, track, col, tissue = press(cut_at=0.8)
    solver = graph_solver(model, capture=False)
    graph = solver.graph
    reads = {"numpy": 0, "sync": 0}
    inside = {"on": False}
    real_numpy = wp.array.numpy

    def numpy(self):
        if inside["on"]:
            reads["numpy"] += 1
        return real_numpy(self)
    monkeypatch.setattr(wp.array, "numpy", numpy)
    for name in ("synchronize", "synchronize_device", "synchronize_stream", "synchronize_event"):
        real = getattr(wp, name)

        def counted(*a, _real=real, **k):
            if inside["on"]:
                reads["sync"] += 1
            return _real(*a, **k)
        monkeypatch.setattr(wp, name, counted)
    real_execute = graph.execute
    calls = []

    def execute(ops):
        outer = not inside["on"]
        inside["on"] = True
        try:
            real_execute(ops)
        finally:
            if outer:
                inside["on"] = False
                calls.append(len(ops))
    monkeypatch.setattr(graph, "execute", execute)
    chunked(model, track, solver, col, tissue)
    assert len(calls) == int(np.ceil(len(TIMES) / CHUNK)) and min(calls) > 100     # every chunk, hundreds of ops
    assert reads == {"numpy": 0, "sync": 0}
    # the plain path does read back inside a chunk (the near flags every step, a restart's state): the count works
    inside["on"] = True
    chunked(model, track, ParticleSolver(model), col, tissue)
    assert reads["numpy"] > 0


def test_two_chunks_of_one_shape_have_one_signature():
    """The operations of chunks 1..n-1 of the press without a cut (each 8 frames going on from the last) have one
    signature: the same kernels, dims, scalars and buffers, so the graph captured for chunk 1 replays for the rest;
    chunk 0 (a restart, one frame fewer) and a chunk of another length have their own."""
    model, track, col, tissue = press()
    solver = graph_solver(model, capture=False)
    sigs = []
    real_launch = solver.graph.launch

    def launch(ops):
        sigs.append(tuple(signature(ops)))
        real_launch(ops)
    solver.graph.launch = launch
    times = TIMES[:33]                                   # chunks 0..3 of 8 frames, then one of 1
    chunked(model, track, solver, col, tissue, times=times)
    assert len(sigs) == 5
    assert sigs[1] == sigs[2] == sigs[3]
    assert sigs[0] != sigs[1] and sigs[4] != sigs[1]
    launches = [op for op in solver.graph.last_ops if op[0] == "launch"]
    assert len(launches) > 4 * 4                        # a launch per step and stage, not one per run


def test_the_cpu_graph_capture_replays_to_the_same_bits():
    """capture=True on the CPU: each chunk shape captured once with wp.ScopedCapture (Warp's CPU graph) and replayed
    with wp.capture_launch for the chunks of that shape; the result equals the plain path bit for bit (a read of the
    device inside the program would see the capture's unrun state and break it)."""
    model, track, col, tissue = press(cut_at=0.8)
    plain = chunked(model, track, ParticleSolver(model), col, tissue)
    solver = graph_solver(model, capture=True)
    graphed = chunked(model, track, solver, col, tissue)
    assert_same(plain, graphed)
    g = solver.graph
    assert g.replays > 0 and g.captures + g.replays == int(np.ceil(len(TIMES) / CHUNK)) and g.captures < 5


def test_graph_arrays_keep_their_place_while_their_shape_does():
    """GraphArrays: the same call order and shapes give the same buffers (new contents); a padded list keeps its
    buffer while its length stays under the same power of two; another shape gets a new one."""
    A = GraphArrays("cpu")
    a = A.upload(np.arange(5, dtype=np.int32), wp.int32, pad=True)
    b = A.upload(np.ones((3, 3), np.float32), wp.vec3)
    A.begin()
    a2 = A.upload(np.arange(7, dtype=np.int32), wp.int32, pad=True)
    b2 = A.upload(np.zeros((3, 3), np.float32), wp.vec3)
    assert a2 is a and b2 is b and a.shape == (8,)
    np.testing.assert_array_equal(a.numpy(), [0, 1, 2, 3, 4, 5, 6, 0])
    A.begin()
    assert A.upload(np.arange(9, dtype=np.int32), wp.int32, pad=True) is not a


@pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device: the captured CUDA graph is checked on a GPU "
                    "(benchmarks/gpu_check.py --only tests runs this file there)")
def test_the_cuda_graph_equals_the_plain_cuda_launches():
    """On a CUDA device: the chunks captured as CUDA graphs and replayed give the plain launches' positions, records
    and end state to float32 rounding (the same kernels; a GPU may fuse differently between launches and graphs:
    within 1e-6 m), and the CPU's within 0.1 mm."""
    model, track, col, tissue = press("cuda", cut_at=0.8)
    plain_solver = ParticleSolver(model)
    plain_solver.use_graph = False
    plain = chunked(model, track, plain_solver, col, tissue)
    solver = ParticleSolver(model)
    assert solver.use_graph and solver.graph is None              # made by the first run
    graphed = chunked(model, track, solver, col, tissue)
    assert solver.graph.capture and solver.graph.captures >= 1 and solver.graph.replays >= 1
    np.testing.assert_allclose(graphed[0], plain[0], atol=1e-6)
    np.testing.assert_allclose(graphed[2][0], plain[2][0], atol=1e-6)
    cm, ct, cc, cti = press("cpu", cut_at=0.8)
    cpu = chunked(cm, ct, ParticleSolver(cm), cc, cti)
    assert np.abs(graphed[0] - cpu[0]).max() < 1e-4
