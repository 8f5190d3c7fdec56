"""The chains part of `jiggle compare`: how far each chain (tail, ear, wing finger: sim.chain) swung, at what
frequency, whether it settles, and whether the skin at its root holds together; metrics.json's "chains" and
chains.png.

A bake with chains holds each chain's tip animated and swung (chain_tips_static, chain_tips_final (T, C, 3)) and
what the swing adds to the skin (chain_delta on chain_vertices; sim.bake.caches). Per chain:

- the tip offset o(t) = |tip_final - tip_static| (metres): its peak (mm, and over the chain's length: bake.json's
  length_m, else the polyline through the chain's swung joints to its tip at frame 0), RMS, last frame, the jump
  from the last frame to the first (a looping cycle's seam); the dominant frequency of the offset vector and the
  settle time as compare's for a muscle (sim.app.report.spectrum, settle_time);
- the root check: the jiggle gradient (rig.skin.quality) of the chain's skin motion, static -> skin_swung (the
  skin following the swung chains, no tissue), on the edges at the chain's root (ROOT_SHARE below), per frame its
  p99.9, max and the torn edges (gradient > 1). Along the chain the skin turns with its bones: a turn by theta
  gives any edge there a gradient of up to 2 sin(theta / 2), which is rotation, not stretch, so it is measured
  only where the chain meets the body, where the skin's weights blend moved and unmoved bones and a tear would
  open. The issue's targets: 0 torn edges and p99.9 <= ROOT_GRADIENT_P999 at every chain's root.

Which chain owns a skin vertex: the nearest chain (distance to the polyline through its swung joints and its tip,
frame 0 of skin_swung); a chain's joints are its run of chain_names from its root (bake.json's per-chain joint
count where present, else up to the next chain's root).
"""
from __future__ import annotations

import math

import numpy as np

from jiggle.rig.skin.quality import TORN
from jiggle.sim.app.outputs.simulate import settle_time
from jiggle.sim.app.report.plots import pyplot, save_figure
from jiggle.sim.app.report.spectrum import STILL, dominant_frequency, muscle_spectrum

BLEND_MAX = 0.999
"""A chain vertex whose skin weight on chain joints is below this blends into the body: the chain's root."""
ROOT_SHARE = 0.25
"""The root edges of a chain: edges with a vertex among the chain's skin vertices whose other vertex, or itself,
moves (its largest |chain_delta| over the clip, 0 for a vertex the chains do not move) less than this share of the
chain's largest. A turn about the root moves the skin in proportion to its distance from it, so this is about the
first quarter of the chain plus the seam to the body, where the skin's weights blend chain and body."""
ROOT_GRADIENT_P999 = 0.5
"""The 99.9th percentile of the root's gradient stays at or below this (the issue's target), every frame."""
CHUNK = 64
"""Frames per gradient launch (bounds the (T, E) temporaries)."""
TOP = 8
"""Chains labelled in chains.png (the largest peaks); the rest are drawn thin grey."""


def chain_joints(data, summary: dict | None) -> list[np.ndarray]:
    """Per chain (data.chain_tip_names), the indices into data.chain_names of its joints, root first.

    summary : bake.json's "chains" or None. Its per-chain "joints" counts cut each run (the joints after the
    last run are riders, bones that follow a chain without being one of its links: left out); without it a
    chain runs from its root to the next chain's root (the last to the end)."""
    names = list(data.chain_names)
    roots = [names.index(n) if n in names else -1 for n in data.chain_tip_names]
    counts = {}
    for entry in (summary or {}).get("chains") or []:
        if isinstance(entry, dict) and isinstance(entry.get("joints"), int):
            counts[entry.get("chain")] = entry["joints"]
    starts = sorted(r for r in roots if r >= 0) + [len(names)]
    out = []
    for name, r in zip(data.chain_tip_names, roots):
        if r < 0:
            out.append(np.zeros(0, np.int64))
            continue
        end = r + counts[name] if name in counts else next(s for s in starts if s > r)
        out.append(np.arange(r, min(end, len(names)), dtype=np.int64))
    return out


def _segment_distance(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, S) distances of points x (N, 3) to segments a-b (S, 3) each."""
    ab = b - a
    L2 = np.einsum("si,si->s", ab, ab)
    t = np.einsum("nsi,si->ns", x[:, None] - a[None], ab) / np.where(L2 > 0, L2, 1.0)
    t = np.clip(np.where(L2 > 0, t, 0.0), 0.0, 1.0)
    return np.linalg.norm(x[:, None] - (a[None] + t[..., None] * ab[None]), axis=2)


def chain_polylines(data, joints: list[np.ndarray]) -> list[np.ndarray]:
    """Per chain, (k + 1, 3) float64 metres at frame 0: its swung joints' origins, root first, then its tip."""
    return [np.concatenate([data.chain_world[0, j, :3, 3].astype(np.float64),
                            data.chain_tips_final[0, c][None].astype(np.float64)])
            for c, j in enumerate(joints)]


def vertex_owner(data, swung: np.ndarray, lines: list[np.ndarray]) -> np.ndarray:
    """(Vc,) int64: the chain (index into chain_tip_names) owning each of data.chain_vertices, the nearest by its
    place on skin_swung's frame 0 (swung (T, V, 3) metres) to the chains' polylines (chain_polylines)."""
    x = np.asarray(swung[0, data.chain_vertices], np.float64)
    if not len(x) or not lines:
        return np.zeros(len(x), np.int64)
    near = np.stack([_segment_distance(x, p[:-1], p[1:]).min(axis=1) if len(p) > 1
                     else np.linalg.norm(x - p[0], axis=1) for p in lines], axis=1)
    return np.argmin(near, axis=1).astype(np.int64)


def root_edges(edges: np.ndarray, num_vertices: int, chain_vertices: np.ndarray, owner: np.ndarray,
               peak: np.ndarray, chains: int, share: float = ROOT_SHARE, weight: np.ndarray | None = None
               ) -> list[np.ndarray]:
    """Per chain, the indices into `edges` (E, 2) of its root edges: with `weight` (the bake's chain_weight), the
    edges with a vertex of the chain whose skin weight blends chain and body joints (0 < w < BLEND_MAX: the root,
    where the chain joins the body); without it (an older bake), ROOT_SHARE's rule.

    chain_vertices : (Vc,) skin vertices the chains move; owner : (Vc,) their chain; peak : (Vc,) metres, each
    one's largest |chain_delta| over the clip; weight : (Vc,) their skin weight on chain joints, or None."""
    own = np.full(num_vertices, -1, np.int64)
    own[chain_vertices] = owner
    out = []
    if weight is not None:
        blend = np.zeros(num_vertices, bool)
        blend[chain_vertices] = (np.asarray(weight) > 0.0) & (np.asarray(weight) < BLEND_MAX)
        for c in range(chains):
            at = (own[edges] == c) & blend[edges]
            out.append(np.flatnonzero(at.any(axis=1)))
        return out
    moved = np.zeros(num_vertices)                      # a vertex the chains do not move: 0
    moved[chain_vertices] = peak
    low = moved[edges].min(axis=1)
    for c in range(chains):
        mine = owner == c
        top = float(peak[mine].max()) if mine.any() else 0.0
        touches = (own[edges] == c).any(axis=1)
        out.append(np.flatnonzero(touches & (low < share * top)) if top > 0 else np.zeros(0, np.int64))
    return out


def root_gradient(quality, static: np.ndarray, swung: np.ndarray, edges: list[np.ndarray]) -> list[dict]:
    """Per chain, its root edges' gradient per frame: {"gradient_p999", "gradient_max", "torn_edges"} (T,) float64
    arrays (zeros for a chain without root edges). quality : rig.skin.quality.SkinQuality of the skin; static,
    swung : (T, V, 3) metres."""
    T = len(static)
    out = [{k: np.zeros(T) for k in ("gradient_p999", "gradient_max", "torn_edges")} for _ in edges]
    used = np.unique(np.concatenate(edges)) if edges and sum(len(e) for e in edges) else np.zeros(0, np.int64)
    if not len(used):
        return out
    col = {int(e): i for i, e in enumerate(used)}
    for a in range(0, T, CHUNK):
        g = quality.gradient(static[a:a + CHUNK], swung[a:a + CHUNK])[:, used]
        for c, e in enumerate(edges):
            if len(e):
                gc = g[:, [col[int(i)] for i in e]]
                out[c]["gradient_p999"][a:a + CHUNK] = np.percentile(gc, 99.9, axis=1)
                out[c]["gradient_max"][a:a + CHUNK] = gc.max(axis=1)
                out[c]["torn_edges"][a:a + CHUNK] = np.count_nonzero(gc > TORN, axis=1)
    return out


def chain_metrics(data, summary: dict | None, quality, swung: np.ndarray) -> tuple[dict, dict]:
    """(metrics.json's "chains", arrays for chains.png) of a bake with chains (data.chain_tip_names not None).

    summary : bake.json's "chains" or None; quality : the skin's SkinQuality (skin_quality.measure's "quality");
    swung : (T, V, 3) metres, data.skin_swung(). arrays: offset (T, C) metres, the tip offsets; tips_static,
    tips_final (T, C, 3) metres."""
    times, T = data.times, data.num_frames
    names = list(data.chain_tip_names)
    C = len(names)
    vec = data.chain_tips_final.astype(np.float64) - data.chain_tips_static
    offset = np.linalg.norm(vec, axis=2)                                       # (T, C) metres
    freqs, spec = muscle_spectrum(vec, np.arange(C + 1), data.fps)             # one "CV" per chain: its tip
    joints = chain_joints(data, summary)
    lines = chain_polylines(data, joints)
    owner = vertex_owner(data, swung, lines)
    peak_v = np.linalg.norm(data.chain_delta, axis=2).max(axis=0) if T else np.zeros(len(owner))
    edges = root_edges(quality.mesh.edges, quality.mesh.num_vertices, data.chain_vertices, owner, peak_v, C,
                       weight=getattr(data, "chain_weight", None))
    grads = root_gradient(quality, data.skin_static, swung, edges)
    baked = {e.get("chain"): e for e in (summary or {}).get("chains") or [] if isinstance(e, dict)}

    per = {}
    for c, name in enumerate(names):
        o, b, g = offset[:, c], baked.get(name) or {}, grads[c]
        k = int(np.argmax(o))
        length = b.get("length_m") if isinstance(b.get("length_m"), (int, float)) else None
        length_from = "bake.json"
        if length is None:
            length = float(np.linalg.norm(np.diff(lines[c], axis=0), axis=1).sum())
            length_from = "the swung joints and tip at frame 0"
        moving = bool(o[k] > STILL)
        n_edges = len(edges[c])
        p999, gmax, torn = float(g["gradient_p999"].max()), float(g["gradient_max"].max()), int(g["torn_edges"].max())
        per[name] = {
            "joints": int(len(joints[c])), "skin_vertices": int(np.count_nonzero(owner == c)),
            "length_mm": 1e3 * length, "length_from": length_from,
            "tip_peak_mm": 1e3 * o[k], "tip_peak_share": o[k] / length if length > 0 else None,
            "tip_peak_time_s": times[k], "tip_peak_frame": k,
            "tip_rms_mm": 1e3 * math.sqrt(float((o ** 2).mean())), "tip_end_mm": 1e3 * o[-1],
            "tip_wrap_mm": 1e3 * float(np.linalg.norm(vec[-1, c] - vec[0, c])),
            "dominant_hz": dominant_frequency(freqs, spec[:, c], T, moving),
            "settle_s": settle_time(times, o, k) if moving else 0.0,
            "swing_share": b.get("swing_share"), "penetrations": b.get("penetrations"),
            "deepest_mm": 1e3 * b["deepest_m"] if isinstance(b.get("deepest_m"), (int, float)) else None,
            "root": {"edges": n_edges,
                     "gradient_p999_max": p999 if n_edges else None, "gradient_max": gmax if n_edges else None,
                     "torn_edges_max": torn, "frames_with_torn_edges": int(np.count_nonzero(g["torn_edges"])),
                     "worst_frame": int(np.argmax(g["gradient_p999"])) if n_edges else None,
                     "pass": bool(torn == 0 and p999 <= ROOT_GRADIENT_P999)},
        }
    measured = [p for p in per.values() if p["root"]["edges"]]
    worst_p = max((p["root"]["gradient_p999_max"] for p in measured), default=None)
    worst_t = max((p["root"]["torn_edges_max"] for p in measured), default=0)
    pens = [p["penetrations"] for p in per.values() if isinstance(p["penetrations"], int)]
    section = {
        "count": C, "names": names,
        "tip_rule": "o(t) = |tip_final - tip_static| (bake.npz chain_tips_*): the tip (the end of the chain's last "
                    "bone) against where the animation puts it; share: peak over the chain's length",
        "frequency_method": "as a muscle's, on the tip's offset vector (one point per chain)",
        "settle_rule": "as a muscle's, on o(t); null: never (a chain kept swinging by the motion)",
        "root_rule": (f"edges with a skin vertex of the chain whose weight on chain joints blends with the body's "
                      f"(0 < w < {BLEND_MAX:g}, bake.npz chain_weight): where the chain joins the body"
                      if getattr(data, "chain_weight", None) is not None else
                      f"edges with a skin vertex of the chain (the nearest chain to it) whose smaller largest "
                      f"|chain_delta| over the clip (0 off the chains' skin) is below {ROOT_SHARE:g} x the chain's "
                      "largest: the seam to the body and the first part of the chain"),
        "root_gradient": "|d_a - d_b| / |s_a - s_b| per root edge, s = skin_static, d = skin_swung - skin_static "
                         f"(the chain's own skin motion, no tissue); torn: > {TORN:g}",
        "chains": per,
        "targets": {
            "root_torn_edges": {"value": worst_t, "limit": 0, "pass": bool(worst_t == 0),
                                "rule": "torn edges at any chain's root, any frame"},
            "root_gradient_p999": {"value": worst_p, "limit": ROOT_GRADIENT_P999,
                                   "pass": bool(worst_p is None or worst_p <= ROOT_GRADIENT_P999),
                                   "rule": "99.9th percentile of the root gradient, every chain, every frame"}},
        "penetrations": int(sum(pens)) if pens else None,
        "swing_share_min": min((p["tip_peak_share"] for p in per.values() if p["tip_peak_share"] is not None),
                               default=None),
        "run": {k: (summary or {}).get(k) for k in ("steps", "step_s", "warmup") if k in (summary or {})},
        "per_frame": {"tip_offset_mm": {n: 1e3 * offset[:, c] for c, n in enumerate(names)},
                      "root_gradient_p999": {n: grads[c]["gradient_p999"] for c, n in enumerate(names)}},
    }
    return section, {"offset": offset, "tips_static": data.chain_tips_static, "tips_final": data.chain_tips_final}


def plot_chains(path: str, times: np.ndarray, names: list[str], section: dict, arrays: dict) -> str:
    """chains.png: left, each chain's tip offset |tip_final - tip_static| over time (mm), labelled with its peak
    and share of its length; right, each tip's height over time, animated (dashed) and swung (solid), one colour
    per chain. The TOP largest peaks are labelled, the rest thin grey."""
    plt = pyplot()
    offset, zs, zf = arrays["offset"], arrays["tips_static"][..., 2], arrays["tips_final"][..., 2]
    order = [int(i) for i in np.argsort(-offset.max(axis=0), kind="stable")] if offset.size else []
    fig, (ax, hx) = plt.subplots(1, 2, figsize=(12, 4.2))
    for c in order[TOP:]:
        ax.plot(times, 1e3 * offset[:, c], color="0.75", lw=0.7)
        hx.plot(times, zf[:, c], color="0.75", lw=0.7)
    for c in order[:TOP]:
        p = section["chains"][names[c]]
        share = p.get("tip_peak_share")
        label = f"{names[c]}: peak {p['tip_peak_mm']:.0f} mm" + ("" if share is None else f" ({100 * share:.0f}%)")
        line, = ax.plot(times, 1e3 * offset[:, c], lw=1.4, label=label)
        hx.plot(times, zs[:, c], color=line.get_color(), lw=1.1, ls="--")
        hx.plot(times, zf[:, c], color=line.get_color(), lw=1.5)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("tip offset (mm)\n|tip_final - tip_static|")
    ax.set_title("how far each chain's tip swung from its animated place")
    ax.set_ylim(bottom=0.0)
    ax.grid(alpha=0.3)
    hx.set_xlabel("time (s)")
    hx.set_ylabel("tip height z (m)")
    hx.set_title("tip height: animated (dashed) and swung (solid)")
    hx.grid(alpha=0.3)
    if order:                                    # the colours are named once, on the left
        ax.legend(fontsize=8, loc="best", framealpha=0.85)
        hx.plot([], [], color="0.2", lw=1.1, ls="--", label="animated")
        hx.plot([], [], color="0.2", lw=1.5, label="swung")
        hx.legend(fontsize=8, loc="best", framealpha=0.85)
    return save_figure(fig, path)
