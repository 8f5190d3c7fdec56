"""The skin-quality part of `jiggle compare`: folds, sharp edges, distortion and jiggle tears per frame
for the LBS, static and final skins of a bake (rig.skin.quality), judged against targets, plotted, and
the worst frames shown close up.

quality.png           folded edges per frame (LBS, static, final; the rest mesh's count and the budget
                      marked) and the jiggle displacement gradient (p99.9, max, torn edges)
quality_closeups.png  the worst QUALITY_SHOTS frames, each zoomed on its worst place: static | final

Targets (the numbers a clean skin keeps, in metrics.json under skin_quality.targets):
- folded edges of the final skin, every frame: at most the rest mesh's own count plus FOLD_BUDGET of
  the edges;
- the muscles, shells and jiggle add at most ADDED_FOLDS more folded edges over the LBS skin underneath,
  summed over the clip (a frame's count is a handful on a clean skin, too few to hold to 10% alone;
  the worst frame's excess is reported beside it);
- no edge torn by the jiggle (gradient > 1), and the 99.9th percentile of the gradient below
  GRADIENT_P999 in every frame;
- in the FEM hero mode, no tetrahedron inverted (det F <= 0) at any output frame (bake.json "fem"): the skin rides CVs
  embedded in the solid, so a solid folded through itself can leave the skin looking clean (fem_target).

The jiggle is the tissue's: measured from the skin that follows the swung chains (BakeData.skin_swung(), the
static skin itself without chains), so a tail's swing is neither jiggle nor a tear; the chains' own skin is
checked at their roots by sim.app.report.chains.
"""
from __future__ import annotations

import numpy as np

from jiggle.rig.skin.quality import FOLDED_COS, JIGGLE_MEASURES, SHARP_COS, SKIN_MEASURES, TORN, SkinQuality
from jiggle.sim.app.report.plots import pyplot, save_figure

FOLD_BUDGET = 0.001
"""Folded edges the final skin may have beyond the rest mesh's own, as a fraction of all edges."""
ADDED_FOLDS = 0.10
"""Folded edges the muscles, shells and jiggle may add over the LBS skin, as a fraction of its folds."""
GRADIENT_P999 = 0.5
"""The 99.9th percentile of the jiggle displacement gradient stays below this."""
QUALITY_SHOTS = 3
"""Close-ups of this many worst frames."""
CHUNK = 64
"""Frames measured per launch (bounds the (T, E) temporaries)."""


SEAM_GAP_MM = 0.01
"""The widest a seam may open, mm (float32 rounding is far below it)."""


def measure(data, reference: np.ndarray | None = None, reference_name: str | None = None) -> dict:
    """Per-frame measures of a bake (sim.bake.caches.BakeData): {"lbs" | "static" | "final": {name:
    (T,)}, "jiggle": {name: (T,)}} (arrays float64; "lbs" only when the bake has its smooth skin) and
    the SkinQuality used (its mesh has the rest counts; the rest is the bake's skin_rest, else the
    first static frame, said in "rest_from").

    reference : (T, V, 3) metres, the skin the jiggle is measured from (the gradient's s and d = final -
    reference), default data.skin_swung(): the skin following the swung chains, so an edge a chain turns rigidly
    is not torn (skin_static without chains); reference_name names it in "reference"."""
    if reference is None:
        reference = data.skin_swung()
    if reference_name is None:
        reference_name = "skin_static" if reference is data.skin_static else "skin_swung"
    rest = data.skin_rest if data.skin_rest is not None else data.skin_static[0]
    q = SkinQuality(rest, data.faces)
    skins = {"lbs": data.skin_lbs, "static": data.skin_static, "final": data.skin_final}
    out = {}
    T = data.num_frames
    for name, skin in skins.items():
        if skin is None:
            continue
        parts = [q.skin(skin[a:a + CHUNK]) for a in range(0, T, CHUNK)]
        out[name] = {k: np.concatenate([p[k] for p in parts]) for k in SKIN_MEASURES}
    parts = [q.jiggle(reference[a:a + CHUNK], data.skin_final[a:a + CHUNK]) for a in range(0, T, CHUNK)]
    out["jiggle"] = {k: np.concatenate([p[k] for p in parts]) for k in JIGGLE_MEASURES}
    out["reference"] = reference_name
    out["seams"] = seam_gaps(rest, data.skin_lbs, data.skin_final)
    out["quality"] = q
    out["rest_from"] = "skin_rest" if data.skin_rest is not None else "the first static frame (no skin_rest)"
    return out


def seam_gaps(rest: np.ndarray, lbs, final: np.ndarray) -> dict:
    """Seams the skin opens: pairs of vertices at one rest place (a mesh split at UV or normal seams) that plain
    skinning keeps together (all pairs without the LBS skin); per frame the widest gap between a pair in the
    final skin, metres: {"pairs": P, "gap_m": (T,)}."""
    from scipy.spatial import cKDTree
    pairs = cKDTree(np.asarray(rest, np.float64)).query_pairs(1e-6, output_type="ndarray")
    if len(pairs) and lbs is not None:
        together = np.linalg.norm(lbs[:, pairs[:, 0]] - lbs[:, pairs[:, 1]], axis=2).max(axis=0) < 1e-6
        pairs = pairs[together]
    if len(pairs) == 0:
        return {"pairs": 0, "gap_m": np.zeros(len(final))}
    return {"pairs": int(len(pairs)),
            "gap_m": np.linalg.norm(final[:, pairs[:, 0]] - final[:, pairs[:, 1]], axis=2).max(axis=1)}


def summarise(m: dict, times: np.ndarray) -> dict:
    """metrics.json's skin_quality: definitions, rest counts, per skin the worst of each measure over
    the frames, the targets with pass/fail, the worst frames, and every per-frame series."""
    q = m["quality"]
    mesh = q.mesh
    E = mesh.num_edges
    worst = {}
    for skin in ("lbs", "static", "final"):
        if skin in m:
            s = m[skin]
            worst[skin] = {"folded_edges_max": int(s["folded_edges"].max()),
                           "folded_edges_mean": float(s["folded_edges"].mean()),
                           "sharp_edges_max": int(s["sharp_edges"].max()),
                           "edge_strain_p99_max": float(s["edge_strain_p99"].max()),
                           "edge_strain_max": float(s["edge_strain_max"].max()),
                           "area_ratio_min": float(s["area_ratio_min"].min()),
                           "area_ratio_max": float(s["area_ratio_max"].max())}
    j = m["jiggle"]
    worst["jiggle"] = {"gradient_p99_max": float(j["gradient_p99"].max()),
                       "gradient_p999_max": float(j["gradient_p999"].max()),
                       "gradient_max": float(j["gradient_max"].max()),
                       "torn_edges_max": int(j["torn_edges"].max()),
                       "frames_with_torn_edges": int(np.count_nonzero(j["torn_edges"]))}
    targets = check_targets(m, mesh.rest_folded, E)
    frames = worst_frames(m, times)
    ref = m.get("reference", "skin_static")
    return {
        "definitions": {
            "folded_edges": f"interior edges whose faces' normals are more than 90 degrees apart "
                            f"(cos < {FOLDED_COS:g})",
            "sharp_edges": f"more than 60 degrees apart (cos < {SHARP_COS:g})",
            "edge_strain": "|edge length / rest length - 1|: its 99th percentile and maximum per frame",
            "area_ratio": "face area / rest area: its minimum and maximum per frame",
            "gradient": (f"|d_a - d_b| / |s_a - s_b| per edge, s = static skin, d = final - static; torn: > {TORN:g}"
                         if ref == "skin_static" else
                         f"|d_a - d_b| / |s_a - s_b| per edge, s = skin_swung, d = final - skin_swung; torn: > {TORN:g} "
                         "(skin_swung = skin_static + chain_delta: the skin following the swung chains, so the chains' "
                         "own turn is not counted)"),
        },
        "reference": ref,
        "edges": E, "faces": int(len(mesh.faces)), "rest_from": m["rest_from"],
        "rest": {"folded_edges": mesh.rest_folded, "sharp_edges": mesh.rest_sharp},
        "worst": worst, "targets": targets, "worst_frames": frames,
        "per_frame": {skin: {k: v for k, v in m[skin].items()} for skin in ("lbs", "static", "final", "jiggle")
                      if skin in m},
    }


def check_targets(m: dict, rest_folded: int, edges: int) -> dict:
    """The module's targets, each {"value", "limit", "pass"} (value: the worst frame's)."""
    final = m["final"]["folded_edges"]
    budget = rest_folded + FOLD_BUDGET * edges
    out = {"final_folded_edges": {"value": int(final.max()), "limit": budget, "pass": bool(final.max() <= budget),
                                  "rule": f"rest mesh's folded edges + {FOLD_BUDGET:.1%} of the edges"}}
    if "lbs" in m:
        lbs = m["lbs"]["folded_edges"]
        k = int(np.argmax(final - lbs))
        ratio = float(final.sum() / max(lbs.sum(), 1.0))
        out["folds_added_over_lbs"] = {
            "value": ratio, "limit": 1.0 + ADDED_FOLDS, "pass": bool(ratio <= 1.0 + ADDED_FOLDS),
            "worst_frame": k, "worst_frame_added": int(final[k] - lbs[k]),
            "rule": f"folded edges of the final skin summed over the clip, over LBS's: at most "
                    f"{1 + ADDED_FOLDS:g}x (worst_frame: the frame with the most folds added)"}
    seams = m.get("seams")
    if seams and seams["pairs"]:
        gap = float(seams["gap_m"].max()) * 1e3
        out["open_seams"] = {"value": gap, "limit": SEAM_GAP_MM, "pass": bool(gap <= SEAM_GAP_MM),
                             "pairs": seams["pairs"],
                             "rule": "widest gap (mm) the final skin opens between vertices split at a seam (one rest "
                                     "place, moved together by plain skinning), every frame"}
    j = m["jiggle"]
    out["torn_edges"] = {"value": int(j["torn_edges"].max()), "limit": 0, "pass": bool(j["torn_edges"].max() == 0),
                         "rule": "edges the jiggle stretches or squeezes by more than their length "
                                 f"(gradient > {TORN:g})"}
    out["gradient_p999"] = {"value": float(j["gradient_p999"].max()), "limit": GRADIENT_P999,
                            "pass": bool(j["gradient_p999"].max() < GRADIENT_P999),
                            "rule": "99.9th percentile of the jiggle displacement gradient, every frame"}
    return out


def fem_target(fem: dict | None) -> dict | None:
    """The hero mode's target from bake.json's "fem" ({"value": the most tets inverted at one output frame, "limit":
    0, "pass", "frames": output frames with any, "min_det": the smallest det F}), None for a bake without a solid."""
    if not isinstance(fem, dict) or not isinstance(fem.get("inverted_max"), int):
        return None
    worst = fem["inverted_max"]
    return {"value": worst, "limit": 0, "pass": worst == 0, "frames": fem.get("frames_with_inverted"),
            "min_det": fem.get("min_det"),
            "rule": "tetrahedra of the hero solid inverted (det F <= 0 against their goal shape) at one output frame"}


def worst_frames(m: dict, times: np.ndarray, count: int = QUALITY_SHOTS) -> list[int]:
    """Up to `count` frames where the final skin looks worst: most folded edges beyond LBS's (or beyond
    the first frame's without LBS) plus torn edges, a quarter second apart at least."""
    final = m["final"]["folded_edges"]
    base = m["lbs"]["folded_edges"] if "lbs" in m else np.zeros_like(final)
    score = (final - base) + m["jiggle"]["torn_edges"] + 1e-3 * final   # ties: the frame with more folds
    gap = 0.25
    chosen = []
    for k in np.argsort(-score, kind="stable"):
        if all(abs(times[k] - times[c]) >= gap for c in chosen):
            chosen.append(int(k))
        if len(chosen) == count:
            break
    return sorted(chosen)


def plot_quality(path: str, times: np.ndarray, summary: dict) -> str:
    """quality.png: folded edges per frame (and the budget), then the jiggle gradient and torn edges."""
    plt = pyplot()
    per = summary["per_frame"]
    fig, (ax, gx) = plt.subplots(1, 2, figsize=(12, 4))
    colours = {"lbs": "0.55", "static": (0.2, 0.45, 0.8), "final": (0.85, 0.35, 0.1)}
    for skin in ("lbs", "static", "final"):
        if skin in per:
            ax.plot(times, per[skin]["folded_edges"], lw=1.3, color=colours[skin], label=skin)
    ax.axhline(summary["rest"]["folded_edges"], color="0.3", ls=":", lw=1, label="rest mesh")
    ax.axhline(summary["targets"]["final_folded_edges"]["limit"], color=(0.7, 0.1, 0.1), ls="--", lw=1,
               label="budget")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"folded edges (> 90 degrees)\nof {summary['edges']}")
    ax.set_title("skin folds per frame")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")
    j = per["jiggle"]
    gx.plot(times, j["gradient_p999"], lw=1.3, label="p99.9")
    gx.plot(times, j["gradient_max"], lw=1.0, color="0.6", label="max")
    gx.axhline(GRADIENT_P999, color=(0.7, 0.1, 0.1), ls="--", lw=1, label=f"p99.9 target {GRADIENT_P999:g}")
    gx.axhline(TORN, color="0.2", ls=":", lw=1, label="torn (1)")
    gx.set_yscale("symlog", linthresh=0.1)
    gx.set_ylim(bottom=0.0)
    gx.set_xlabel("time (s)")
    gx.set_ylabel("jiggle displacement gradient\n|d_a - d_b| / |s_a - s_b|")
    torn = j["torn_edges"]
    gx.set_title(f"jiggle gradient per frame (torn edges: max {int(torn.max())}, "
                 f"{int(np.count_nonzero(torn))} frames)")
    gx.grid(alpha=0.3)
    gx.legend(fontsize=8, loc="upper right")
    return save_figure(fig, path)


def render_closeups(data, m: dict, frames: list[int], disp: np.ndarray, path: str,
                    reference: np.ndarray | None = None) -> str | None:
    """quality_closeups.png: one row per frame of `frames`, static | final, zoomed on the place with
    the most folded and torn edges of the final skin (SkinQuality.worst_vertex), seen along the
    static skin's normal there made level (the picture stays upright); the final skin coloured by
    displacement on the bake's scale. reference : (T, V, 3) metres, the "static" panel and the skin the
    tears are measured from (default data.skin_static; compare passes skin_swung for a bake with chains)."""
    if not frames:
        return None
    static = data.skin_static if reference is None else reference
    label = "static" if static is data.skin_static else "static + chains"
    from jiggle.rig.character.normals import VertexNormals
    from jiggle.sim.app.report.compare_render import SideBySide, write_png
    q = m["quality"]
    top = float(disp.max()) * 1e3 if disp.size else 0.0
    clim = (0.0, top if top > 1e-3 else 1.0)
    extent = np.ptp(static[frames[0]], axis=0).max()
    half = 0.12 * extent                               # a hand's width around the place on a human
    normals = VertexNormals(data.faces, data.skin_static.shape[1])
    r = SideBySide(data.faces, data.skin_static.shape[1], clim, panel=(480, 400))
    rows = []
    try:
        for k in frames:
            v = q.worst_vertex(data.skin_final[k], static[k])
            c = static[k][v].astype(np.float64)
            n = normals(static[k].astype(np.float64))[v]
            side = n[:2] / np.linalg.norm(n[:2]) if np.linalg.norm(n[:2]) > 0.2 else np.array([0.0, -1.0])
            direction = np.array([side[0], side[1], 0.35])  # level with the place, a little from above
            direction /= np.linalg.norm(direction)
            box = np.stack([c - half, c + half])
            fin = m["final"]["folded_edges"][k]
            lbs = f", LBS {int(m['lbs']['folded_edges'][k])}" if "lbs" in m else ""
            rows.append(r.draw(static[k], data.skin_final[k], box, direction,
                               f"{label}  frame {k}, t = {data.times[k]:.2f} s, folded "
                               f"{int(m['static']['folded_edges'][k])}{lbs}",
                               f"final  folded {int(fin)}, torn {int(m['jiggle']['torn_edges'][k])}"))
    finally:
        r.close()
    width = max(im.shape[1] for im in rows)
    rows = [np.pad(im, ((0, 0), (0, width - im.shape[1]), (0, 0)), constant_values=255) for im in rows]
    return write_png(np.concatenate(rows, axis=0), path)


def fmt_targets(targets: dict) -> str:
    """One line: each target's worst value against its limit, ok or FAIL."""
    def num(x):
        return f"{x:.3g}" if isinstance(x, float) else str(x)
    return "; ".join(f"{name} {num(t['value'])} (limit {num(t['limit'])}) {'ok' if t['pass'] else 'FAIL'}"
                     for name, t in targets.items())
