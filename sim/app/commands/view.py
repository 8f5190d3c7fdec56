"""`jiggle view OUT_DIR`: a bake played in the browser, with sliders that re-simulate it (sim/app/view/).
"""
from __future__ import annotations

import sys
import time


def port(text: str) -> int:
    import argparse
    try:
        p = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port in 0..65535, got {p}")
    return p


def open_viewer(out_dir: str, host: str = "127.0.0.1", port: int = 8080, paused: bool = False, tune: bool = True,
                log=lambda s: print(f"  {s}", file=sys.stderr)):
    """The ViewerPage of the bake in out_dir, serving (InputError for a folder that is not a finished bake
    of this jiggle's format). Tuning rebuilds the setup in a background thread (the page plays meanwhile)."""
    from jiggle.sim.app.view.page import ViewerPage
    from jiggle.sim.app.view.playback import Playback, open_bake, read_quality
    from jiggle.sim.app.view.tuning import NotTunable, Tuner
    from jiggle.sim.bake.setup import VERSION
    data, summary = open_bake(out_dir)
    pb = Playback(data, summary, read_quality(out_dir, data.num_frames))
    factory = None
    if tune:
        def factory():
            if summary is None:
                raise NotTunable("the folder has no bake.json (its parameters)")
            version = (summary.get("params") or {}).get("jiggle_bake")
            if version != VERSION:
                raise NotTunable(f"bake.json is from bake version {version}, this jiggle re-simulates version "
                                 f"{VERSION}: bake it again to tune it")
            return Tuner(summary, data.muscle_cvs_static, log=log)
    formats = tuple((summary or {}).get("files", {}).keys()) or ("npz", "usdc")
    return ViewerPage(pb, out_dir, host=host, port=port, paused=paused, tuner_factory=factory, log=log,
                      formats=formats)


def run(args) -> int:
    page = open_viewer(args.out_dir, args.host, args.port, paused=args.paused, tune=not args.no_tune)
    print(f"jiggle view: {page.url} (the bake in {args.out_dir}; Ctrl-C stops)", flush=True)
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"  shared: listening on {args.host}, port {page.server.get_port()}; anyone who reaches this machine "
              "can open the page and move its sliders", file=sys.stderr, flush=True)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        page.stop()
        raise KeyboardInterrupt(f"(the viewer at {page.url} stopped)") from None
    return 0


def add_parser(sub) -> None:
    """The `jiggle view` subcommand and its options."""
    p = sub.add_parser("view", help="play a bake in the browser and tune its jiggle live",
                       description="Serve a web page (viser) that plays the bake in OUT_DIR: the final skin over "
                                   "its frames (play, scrub, loop, speed), static | dynamic | side by side | "
                                   "overlaid, the displacement heat map (the report's colours), the muscles, the "
                                   "skeleton, each muscle's jiggle amplitude (click one to highlight it and its "
                                   "skin), the frame's skin quality (after `jiggle compare`). Its Tune panel "
                                   "rebuilds the bake's setup from bake.json and re-simulates as its sliders move "
                                   "(per-muscle strength, frequency, damping ratio, goal weight scale; the global "
                                   "blend); 'save scene' writes a scene TOML `jiggle bake` reproduces exactly. "
                                   "Only the page's own files are served; the bake's frames go over its websocket.")
    p.add_argument("out_dir", metavar="OUT_DIR", help="a folder baked by `jiggle bake --out OUT_DIR`")
    p.add_argument("--port", type=port, default=8080, help="port to serve on (default 8080; the next free one "
                   "when taken; 0: any)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1, this machine only; "
                   "0.0.0.0 shares the page on the network)")
    p.add_argument("--paused", action="store_true", help="start paused at frame 0 (default: playing)")
    p.add_argument("--no-tune", action="store_true", help="play only: do not rebuild the setup for the sliders")
    p.set_defaults(func=run)

