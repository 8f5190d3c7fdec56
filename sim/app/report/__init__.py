"""`jiggle compare`'s report, and the pictures other commands share: what a bake's jiggle did, measured and drawn.

compare (the numbers of metrics.json and the order of the work), skin_quality (folds, tears, open seams, the
jiggle's gradient), glb (a bake's glb read back as an engine plays it), plots (Matplotlib figures), render,
compare_render and mesh_render (off-screen PyVista pictures), page (report.html). They take a bake's folder and
give files beside it; nothing here changes a bake.
"""
