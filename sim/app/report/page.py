"""report.html of `jiggle compare`: one self-contained page (plain HTML and CSS, pictures and the
video embedded as base64 data URIs, no external URL), so it can be mailed or opened offline.

Sections: title, source and settings (from the bake's params), key numbers, skin quality (targets,
the worst of each measure per skin, the plot and the close-ups), chains (a bake with them: the root targets, a
table per chain, chains.png), collisions (a bake with them: key
numbers, the per-frame plot, the table of which muscle hit what), the muscle table (largest peak
first), the plots, the peak picture, the video.
"""
from __future__ import annotations

import base64
import html
import json
import os

from jiggle.rig.base.atomic import atomic_path

MIME = {".png": "image/png", ".gif": "image/gif", ".mp4": "video/mp4"}
PLOTS = (("amplitude", "Jiggle amplitude"), ("limits_plot", "Offset over reach: how near each muscle comes to its limit"),
         ("energy", "Jiggle energy"), ("spectrum", "Spectrum"), ("displacement_plot", "Skin displacement"))

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { font-size: 1.2em; margin-top: 1.6em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { padding: 0.25em 0.7em; border-bottom: 1px solid #e4e4e4; text-align: left; overflow-wrap: anywhere; }
td.n { text-align: right; font-variant-numeric: tabular-nums; }
.kv th { color: #555; font-weight: normal; }
img, video { max-width: 100%; border: 1px solid #ddd; }
.note { color: #666; font-size: 0.85em; }
"""


def data_uri(path: str) -> str:
    """The file at `path` as a base64 data URI (type from its suffix)."""
    mime = MIME.get(os.path.splitext(path)[1].lower(), "application/octet-stream")
    with open(path, "rb") as fh:
        return f"data:{mime};base64," + base64.b64encode(fh.read()).decode("ascii")


def _e(value) -> str:
    """Escaped text of a value; None as a dash, dicts and lists as compact JSON."""
    if value is None:
        return "&ndash;"
    if isinstance(value, (dict, list, bool)):
        value = json.dumps(value, separators=(", ", ": "))
    return html.escape(str(value))


def _num(value, fmt: str = ".2f") -> str:
    return "&ndash;" if value is None else format(value, fmt)


def _kv(rows) -> str:
    body = "".join(f"<tr><th>{_e(k)}</th><td>{v}</td></tr>" for k, v in rows)
    return f'<table class="kv">{body}</table>'


def _muscle_table(muscles: dict, energy_unit: str) -> str:
    head = ("muscle", "kind", "peak (mm)", "at (s)", "RMS (mm)", f"peak energy ({energy_unit})",
            f"mean energy ({energy_unit})", "dominant (Hz)", "set (Hz)", "damping", "settle (s)",
            "peak / reach", "near limit (% frames)", "hard stops")
    rows = []
    for name, m in muscles.items():        # metrics.json lists them largest peak first
        cells = [_e(name), _e(m.get("kind")), _num(m.get("peak_mm")), _num(m.get("peak_time_s"), ".3f"),
                 _num(m.get("rms_mm")), _num(m.get("peak_energy_j"), ".3g"), _num(m.get("mean_energy_j"), ".3g"),
                 _num(m.get("dominant_hz")), _num(m.get("frequency_hz")), _num(m.get("damping_ratio")),
                 "never" if m.get("settle_s") is None and m.get("peak_mm") else _num(m.get("settle_s"), ".3f"),
                 _num(m.get("peak_reach_fraction")),
                 _num(None if m.get("near_limit_fraction") is None else 100.0 * m["near_limit_fraction"], ".1f"),
                 _e(m.get("hard_stops")) if m.get("hard_stops") is not None else _num(None)]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" if i < 2 else f'<td class="n">{c}</td>'
                                     for i, c in enumerate(cells)) + "</tr>")
    return ("<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>" + "".join(rows) + "</table>")


def _limits_section(lim: dict) -> list[str]:
    """Near the limit: how much of the clip the muscles spend near their reach, the hard stops, and a flag
    with advice per muscle above the threshold."""
    if not lim or lim.get("muscles_with_reach", 0) == 0:
        return []
    frac = lim.get("near_limit_fraction_all")
    worst = lim.get("worst") or {}
    rows = [("near the limit, all muscles and frames", f"{_num(None if frac is None else 100.0 * frac, '.2f')} %"),
            ("muscles near their limit at some frame", f"{_e(lim.get('muscles_near_limit'))} of "
                                                       f"{_e(lim.get('muscles_with_reach'))}"),
            ("most often", f"{_e(worst.get('muscle'))}: "
                           f"{_num(None if worst.get('near_limit_fraction') is None else 100.0 * worst['near_limit_fraction'], '.1f')} % of frames"),
            ("hard stops", _e(lim.get("hard_stops_total")) if lim.get("hard_stops_total") is not None else "not recorded")]
    parts = ["<h2>Near the limit</h2>", _kv(rows),
             f'<p class="note">{_e(lim.get("rule"))}. hard stop: {_e(lim.get("hard_stop_rule"))}.</p>']
    flags = lim.get("flags") or []
    if flags:
        items = "".join(f"<li><b>FLAG</b> {_e(f.get('muscle'))} is near its limit in "
                        f"{_num(100.0 * f.get('near_limit_fraction', 0.0), '.1f')} % of frames (more than "
                        f"{_num(100.0 * lim.get('flag_above', 0.05), 'g')} %): {_e(f.get('advice'))}</li>"
                        for f in flags)
        parts.append(f"<ul>{items}</ul>")
    else:
        parts.append(f'<p>pass: no muscle is near its limit in more than '
                     f'{_num(100.0 * lim.get("flag_above", 0.05), "g")} % of frames.</p>')
    return parts


def _quality_section(q: dict, files: dict) -> list[str]:
    """Skin quality: the targets (pass / FAIL), a table of the worst frame's value of each measure per
    skin, the plot and the close-ups."""
    if not q:
        return []
    rows = []
    for name, t in (q.get("targets") or {}).items():
        ok = t.get("pass")
        verdict = '<b style="color:#1a7f37">ok</b>' if ok else '<b style="color:#b42318">FAIL</b>'
        rows.append((name, f"{_e(_short(t.get('value')))} (limit {_e(_short(t.get('limit')))}) {verdict}"
                           f' <span class="note">{_e(t.get("rule"))}</span>'))
    worst = q.get("worst") or {}
    cols = [s for s in ("lbs", "static", "final") if s in worst]
    measures = (("folded_edges_max", "folded edges (> 90 deg), most in a frame"),
                ("sharp_edges_max", "sharp edges (> 60 deg), most in a frame"),
                ("edge_strain_p99_max", "edge strain p99, worst frame"), ("edge_strain_max", "edge strain max"),
                ("area_ratio_min", "face area / rest, least"), ("area_ratio_max", "face area / rest, most"))
    table = ("<table><tr><th>measure</th>" + "".join(f"<th>{_e(c)}</th>" for c in cols) + "</tr>"
             + "".join(f"<tr><td>{_e(label)}</td>" + "".join(
                 f'<td class="n">{_e(_short(worst[c].get(key)))}</td>' for c in cols) + "</tr>"
                 for key, label in measures) + "</table>")
    j = worst.get("jiggle") or {}
    rest = q.get("rest") or {}
    parts = ["<h2>Skin quality</h2>", _kv(rows), table,
             f'<p class="note">{_e(q.get("edges"))} edges; the rest mesh has {_e(rest.get("folded_edges"))} '
             f'folded and {_e(rest.get("sharp_edges"))} sharp edges (rest from {_e(q.get("rest_from"))}). '
             f'Jiggle gradient: p99 up to {_e(_short(j.get("gradient_p99_max")))}, p99.9 up to '
             f'{_e(_short(j.get("gradient_p999_max")))}, max {_e(_short(j.get("gradient_max")))}; torn edges up to '
             f'{_e(j.get("torn_edges_max"))} in a frame, in {_e(j.get("frames_with_torn_edges"))} frames.</p>']
    if "quality_plot" in files:
        parts.append(f'<img alt="skin quality per frame" src="{data_uri(files["quality_plot"])}">')
    if "quality_closeups" in files:
        parts += [f'<img alt="worst frames close up" src="{data_uri(files["quality_closeups"])}">',
                  f'<p class="note">the worst frames {_e(q.get("worst_frames"))} close up at the place with the '
                  "most folded and torn edges: static | final.</p>"]
    return parts


def _glb_section(g: dict, files: dict) -> list[str]:
    """Jiggle bones (metrics.json's "glb", a bake with --formats glb): the file's fit in numbers and its worst
    frame close up."""
    s = g.get("summary") or {}
    rows = [("file", f"{_e(g.get('file'))} ({_e(g.get('bytes'))} bytes, {_e(g.get('bones'))} jiggle bones)"),
            ("RMS per frame, worst", f"{_e(_short(s.get('rms_mm_max')))} mm"),
            ("p99 per frame, worst", f"{_e(_short(s.get('p99_mm_max')))} mm"),
            ("largest distance", f"{_e(_short(s.get('max_mm')))} mm"),
            ("the bones make, at least", f"{_e(_short(s.get('share_min')))} of the muscles' motion"),
            ("made right, at least", f"{_e(_short(s.get('explained_min')))} (1 - sum |played - final| / "
                                     "sum |final - lbs|)")]
    parts = ["<h2>Jiggle bones (glb)</h2>", _kv(rows)]
    if "glb_closeup" in files:
        parts += [f'<img alt="the glb worst frame close up" src="{data_uri(files["glb_closeup"])}">',
                  f'<p class="note">frame {_e(g.get("worst_frame"))}, the worst for p99: skin_final | the skin '
                  "the glb plays (read back by jiggle's glTF reader), coloured by the distance between them.</p>"]
    return parts


CHAINS_CAPTION = ("Chains: each tip's offset from where the animation puts it (left) and its height, animated "
                  "dashed, swung solid (right).")


def _chain_section(c: dict, files: dict) -> list[str]:
    """Chains (metrics.json's "chains", a bake with them): the root targets (pass / FAIL), one row per chain (its
    tip's swing, frequency, settling, penetrations and its root's gradient) and chains.png with its caption."""
    if not c:
        return []
    rows = []
    for name, t in (c.get("targets") or {}).items():
        verdict = '<b style="color:#1a7f37">ok</b>' if t.get("pass") else '<b style="color:#b42318">FAIL</b>'
        rows.append((name, f"{_e(_short(t.get('value')))} (limit {_e(_short(t.get('limit')))}) {verdict}"
                           f' <span class="note">{_e(t.get("rule"))}</span>'))
    head = ("chain", "joints", "length (mm)", "tip peak (mm)", "share of length", "at (s)", "RMS (mm)",
            "dominant (Hz)", "settle (s)", "penetrations", "root edges", "root p99.9", "root max", "root torn")
    body = []
    for name, p in (c.get("chains") or {}).items():
        r = p.get("root") or {}
        share = p.get("tip_peak_share")
        cells = [_e(name), _e(p.get("joints")), _num(p.get("length_mm"), ".0f"), _num(p.get("tip_peak_mm"), ".1f"),
                 _num(None if share is None else 100.0 * share, ".1f") + (" %" if share is not None else ""),
                 _num(p.get("tip_peak_time_s"), ".3f"), _num(p.get("tip_rms_mm"), ".1f"), _num(p.get("dominant_hz")),
                 "never" if p.get("settle_s") is None else _num(p.get("settle_s"), ".3f"),
                 _e(p.get("penetrations")), _e(r.get("edges")), _num(r.get("gradient_p999_max"), ".3f"),
                 _num(r.get("gradient_max"), ".3f"), _e(r.get("torn_edges_max"))]
        body.append("<tr>" + "".join(f"<td>{x}</td>" if i == 0 else f'<td class="n">{x}</td>'
                                     for i, x in enumerate(cells)) + "</tr>")
    parts = ["<h2>Chains</h2>", _kv(rows),
             "<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>" + "".join(body) + "</table>",
             f'<p class="note">tip: {_e(c.get("tip_rule"))}. root edges: {_e(c.get("root_rule"))}; gradient: '
             f'{_e(c.get("root_gradient"))}. The tissue\'s numbers above are measured from the skin that follows the '
             "swung chains.</p>"]
    if "chains_plot" in files:
        parts.append(f'<figure><img alt="chains" src="{data_uri(files["chains_plot"])}">'
                     f"<figcaption>{_e(CHAINS_CAPTION)}</figcaption></figure>")
    return parts


def _collision_section(c: dict, files: dict) -> list[str]:
    """Collisions (metrics.json's "collisions", a bake with them): key numbers, the skin inside capsules,
    the per-frame plot and the table of which muscle hit what (deepest first)."""
    if not c:
        return []
    si = c.get("skin_inside") or {}
    rows = [("frames with a particle in contact", _e(c.get("frames_in_contact"))),
            ("deepest penetration (before correction)", f"{_num(c.get('max_penetration_mm'), '.3g')} mm"),
            ("colliders", f"{_e(c.get('colliders'))} (capsules and the floor at z = {_num(c.get('floor_m'), '.3f')} m),"
                          f" {_e(c.get('pairs_checked'))} muscle-capsule pairs, friction {_e(c.get('friction'))}")]
    if si:
        verdict = ('<b style="color:#1a7f37">ok</b>' if si.get("max_final", 0) <= si.get("max_static", 0)
                   else '<b style="color:#b42318">more than static</b>')
        rows.append(("skin vertices inside another part's capsule (per frame)",
                     f"static: max {_e(si.get('max_static'))}, mean {_num(si.get('mean_static'))}; final: max "
                     f"{_e(si.get('max_final'))}, mean {_num(si.get('mean_final'))} {verdict}; final above static in "
                     f"{_e(si.get('frames_final_above_static'))} frames"))
        if "max_pulled_back" in si:
            rows.append(("final skin pulled back out of a capsule",
                         f"{_e(si.get('pulled_back_frames'))} frames, at most {_e(si.get('max_pulled_back'))} vertices "
                         f"in a frame, by at most {_num(si.get('max_pull_mm'), '.3g')} mm (along their jiggle)"))
    parts = ["<h2>Collisions</h2>", _kv(rows)]
    if "contacts_plot" in files:
        parts.append(f'<img alt="contacts per frame" src="{data_uri(files["contacts_plot"])}">')
    pairs = c.get("pairs") or []
    if pairs:
        head = ("muscle", "hit", "frames in contact", "max penetration (mm)", "impulse (N s)")
        body = "".join(f"<tr><td>{_e(p.get('muscle'))}</td><td>{_e(p.get('hit'))}</td>"
                       f'<td class="n">{_e(p.get("frames"))}</td>'
                       f'<td class="n">{_num(p.get("max_penetration_mm"), ".3g")}</td>'
                       f'<td class="n">{_num(p.get("impulse_Ns"), ".3g")}</td></tr>' for p in pairs)
        parts.append("<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>" + body + "</table>")
    else:
        parts.append('<p class="note">no particle touched a capsule or the floor.</p>')
    parts.append(f'<p class="note">{_e(c.get("method"))}. {_e(si.get("rule"))}.</p>' if si else
                 f'<p class="note">{_e(c.get("method"))}.</p>')
    return parts


def _short(value):
    return f"{value:.3g}" if isinstance(value, float) else value


def _activation_section(a: dict, files: dict) -> list[str]:
    """Activation (metrics.json's "activation", a bake with `--activation on`): the hardest-working muscles' peak
    and mean and when they peaked, and activation.png."""
    if not a:
        return []
    head = ("muscle", "peak", "mean", "peak at (s)")
    body = "".join(f"<tr><td>{_e(n)}</td><td class=\"n\">{_num(v.get('peak'), '.2f')}</td>"
                   f"<td class=\"n\">{_num(v.get('mean'), '.2f')}</td><td class=\"n\">{_num(v.get('peak_time_s'), '.3f')}"
                   "</td></tr>" for n, v in list((a.get("muscles") or {}).items())[:12])
    parts = ["<h2>Activation</h2>", f'<p class="note">{_e(a.get("rule"))}</p>',
             "<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>" + body + "</table>"]
    if "activation_plot" in files:
        parts.append(f'<img alt="activation over time" src="{data_uri(files["activation_plot"])}">')
    return parts


def render_report(metrics: dict, files: dict) -> str:
    """The page as a string. metrics : the metrics.json dict. files : key -> path of the outputs
    (amplitude, energy, spectrum, displacement_plot, peak, video; absent keys are left out)."""
    m = metrics
    skin, peak = m.get("skin", {}), m.get("peak", {})
    pv, pr = skin.get("per_vertex_max", {}), skin.get("per_vertex_rms", {})
    parts = [f"<h1>{_e(m.get('title', 'jiggle compare'))}</h1>",
             f'<p class="note">bake: {_e(m.get("bake"))}</p>',
             "<h2>Source</h2>", _kv((k, _e(v)) for k, v in (m.get("source") or {}).items())]
    settings = m.get("settings") or {}
    if settings:
        parts += ["<h2>Settings</h2>", _kv((k, _e(v)) for k, v in settings.items())]
    parts += ["<h2>Key numbers</h2>", _kv([
        ("frames", f"{m.get('frames')} at {_num(m.get('fps'), 'g')} fps, {_num(m.get('duration_s'), '.3f')} s"),
        ("skin vertices", _e(m.get("vertices"))),
        ("largest skin displacement" + (" (tissue: from the skin following the swung chains)"
                                        if m.get("reference") == "skin_swung" else ""),
         f"{_num(skin.get('max_mm'))} mm (vertex {_e(skin.get('max_vertex'))}, "
                                      f"frame {_e(skin.get('max_frame'))}, {_num(skin.get('max_time_s'), '.3f')} s)"),
        ("peak frame", f"{_e(peak.get('frame'))} at {_num(peak.get('time_s'), '.3f')} s: largest "
                       f"{_num(peak.get('max_mm'))} mm, RMS {_num(peak.get('rms_mm'))} mm ({_e(peak.get('rule'))})"),
        ("per-vertex largest (mm)", f"p50 {_num(pv.get('p50_mm'))}, p95 {_num(pv.get('p95_mm'))}, "
                                    f"p99 {_num(pv.get('p99_mm'))}, mean {_num(pv.get('mean_mm'))}"),
        ("per-vertex RMS (mm)", f"p50 {_num(pr.get('p50_mm'))}, p95 {_num(pr.get('p95_mm'))}, "
                                f"p99 {_num(pr.get('p99_mm'))}, max {_num(pr.get('max_mm'))}"),
        ("muscles", _e(m.get("muscle_count"))),
    ])]
    parts += _quality_section(m.get("skin_quality") or {}, files)
    parts += _chain_section(m.get("chains") or {}, files)
    parts += _collision_section(m.get("collisions") or {}, files)
    parts += _activation_section(m.get("activation") or {}, files)
    if m.get("glb"):
        parts += _glb_section(m["glb"], files)
    unit = m.get("energy_unit", "J")
    parts += _limits_section(m.get("limits") or {})
    parts += ["<h2>Muscles</h2>", _muscle_table(m.get("muscles") or {}, unit),
              f'<p class="note">amplitude: {_e(m.get("amplitude"))}. energy ({_e(unit)}): {_e(m.get("energy"))}. '
              f'frequency: {_e(m.get("frequency_method"))}; resolution {_num(m.get("frequency_resolution_hz"), ".3g")} '
              f'Hz. settle: {_e(m.get("settle_rule"))}.</p>']
    parts.append("<h2>Plots</h2>")
    for key, caption in PLOTS:
        if key in files:
            parts.append(f'<figure><img alt="{_e(caption)}" src="{data_uri(files[key])}">'
                         f"<figcaption>{_e(caption)}</figcaption></figure>")
    if "peak" in files:
        parts += ["<h2>Peak frame</h2>", f'<img alt="peak frame" src="{data_uri(files["peak"])}">',
                  '<p class="note">left: static skin; right: with the jiggle, coloured by how far it moved.</p>']
    if "video" in files:
        v = m.get("video") or {}
        src = data_uri(files["video"])
        media = (f'<video controls loop muted autoplay playsinline src="{src}"></video>'
                 if files["video"].endswith(".mp4") else f'<img alt="clip" src="{src}">')
        parts += ["<h2>Clip</h2>", media,
                  f'<p class="note">{_e(v.get("frames"))} frames at {_num(v.get("fps"), ".3g")} fps (every '
                  f'{_num(v.get("every"), ".3g")} bake frames, real time); colour scale '
                  f'{_e(v.get("colour_scale_mm"))} mm for all frames.</p>']
    timings = m.get("timings_s") or {}
    if timings:
        parts.append('<p class="note">timings (s): ' + ", ".join(f"{_e(k)} {_num(t, '.2f')}"
                                                               for k, t in timings.items()) + "</p>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{_e(m.get('title', 'jiggle compare'))}</title><style>{CSS}</style></head>\n<body>\n"
            + "\n".join(parts) + "\n</body></html>\n")


def write_report(path: str, metrics: dict, files: dict) -> str:
    """Write render_report(metrics, files) to `path`, atomically; return the path."""
    text = render_report(metrics, files)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(text)
    return path
