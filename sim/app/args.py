"""The command line's shared parts: the parser class, argument types, and the argument groups that
several subcommands take (clip reading, character and generated body, mesh reading, joint maps, the
bake options of `bake` and `demo`), each defined once.
"""
from __future__ import annotations

import argparse
import contextlib
import contextvars
import sys

EXIT_USER_ERROR = 2


_RAISING = contextvars.ContextVar("jiggle_parser_raising", default=False)


class Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's own exit code is 2 too; keep the one-line style
        if _RAISING.get():
            from jiggle.rig.base.errors import InputError
            raise InputError(message)
        self.print_usage(sys.stderr)
        self.exit(EXIT_USER_ERROR, f"jiggle: error: {message}\n")


@contextlib.contextmanager
def raising_errors():
    """Parsers raise InputError (the message the command line prints) instead of exiting: the public API parses
    its keyword arguments with the command's own parser (jiggle/api.py)."""
    token = _RAISING.set(True)
    try:
        yield
    finally:
        _RAISING.reset(token)


def output_options(p: argparse.ArgumentParser, top: bool = False) -> None:
    """--quiet and --verbose: how much a command prints. Every parser takes them, so they may come before or
    after the subcommand; a subcommand's copy has no default, not to hide the one given before it."""
    g = p.add_argument_group("output").add_mutually_exclusive_group()
    default = False if top else argparse.SUPPRESS
    g.add_argument("-q", "--quiet", action="store_true", default=default,
                   help="errors only: no progress bars, notices, warnings or list of files written")
    g.add_argument("-v", "--verbose", action="store_true", default=default,
                   help="also Warp's start-up and kernel-load lines with their timings, the command's time, and "
                        "every warning (NumPy's overflow and invalid-value ones too), which are hidden by default")


def _real(name, ok, expected):
    """A float argument type whose messages name the option: not a number, or not `expected`."""
    def conv(v):
        try:
            x = float(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {v!r}") from None
        if not ok(x):    # written so that NaN fails every check
            raise argparse.ArgumentTypeError(f"{name} must be {expected}, got {v!r}")
        return x
    return conv


def non_negative(name):
    return _real(name, lambda x: 0 <= x < float("inf"), "zero or more")


def positive(name):
    return _real(name, lambda x: 0 < x < float("inf"), "a positive number")


def unit_interval(name):
    return _real(name, lambda x: 0.0 <= x <= 1.0, "in [0, 1]")


def count(name, zero=False):
    least = 0 if zero else 1

    def conv(v):
        try:
            n = int(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a whole number, got {v!r}") from None
        if n < least:
            raise argparse.ArgumentTypeError(f"{name} must be at least {least}, got {v!r}")
        return n
    return conv


def animation(value):
    if value is None:
        return None
    return int(value) if value.lstrip("-").isdigit() else value


def clip_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("clip reading")
    g.add_argument("--skeleton", metavar="ASF", help="the ASF skeleton of an AMC clip (default: the one .asf beside it)")
    g.add_argument("--animation", metavar="NAME|INDEX", help="glTF animation to play (default: the first)")
    g.add_argument("--scale", type=float, metavar="M", help="BVH metres per file unit (default: CMU recognised, else guessed from height)")
    g.add_argument("--tpose", choices=["auto", "skip", "keep"], default="auto",
                   help="BVH first frame: auto drops a T-pose added by converters (CMU), skip always drops it, keep never (default: auto)")


def character_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("character and generated body")
    if p.prog.split()[-1] not in ("body", "fit", "simulate"):
        g.add_argument("--no-character", action="store_true", help="skeleton only: no body, no skinning")
        g.add_argument("--skinning", choices=["lbs", "dqs"], default="lbs",
                       help="linear blend or dual-quaternion skinning (default: lbs)")
    influences_option(g)
    g.add_argument("--resolution", type=count("--resolution"), metavar="N",
                   help="generated body: target vertex count, 10000-40000 useful (default: 20000)")
    from jiggle.rig.character.body import BodyOptions
    for name, what in (("belly", "belly"), ("chest", "chest"), ("glutes", "glutes"), ("upper-arms", "upper arms")):
        default = getattr(BodyOptions(), name.replace("-", "_"))
        g.add_argument(f"--{name}", type=non_negative(f"--{name}"), metavar="M",
                       help=f"generated body: fat on the {what}, metres it pushes the skin out; 0 for none "
                            f"(default: {default:g})")


def mesh_options(g) -> None:
    """How to read a character file: --skin, --unit, --up (play and fit)."""
    g.add_argument("--skin", type=int, default=0, metavar="N", help="which skin of a glTF character (default: 0)")
    g.add_argument("--unit", metavar="UNIT", help="the character file's unit: auto, m, cm, mm, in, ft or metres per "
                   "unit (default: auto: metres unless the height says cm or mm)")
    g.add_argument("--up", choices=["auto", "y", "z"], default="auto",
                   help="up axis of an OBJ/PLY/STL character (default: auto, the longer of y and z)")


def map_options(g, clip: bool = True, alias: bool = True) -> None:
    """The joint maps, one name in every command: --character-map names the roles of the character's
    joints, for the muscle template and for retargeting (--joint-map is its old name, kept unless
    `alias` is False); --clip-map the clip's, for retargeting (when `clip`)."""
    names = ("--character-map", "--joint-map") if alias else ("--character-map",)
    g.add_argument(*names, dest="character_map", metavar="TOML|PRESET",
                   help="joint map of the character: the roles of its joints, for the muscle template and for "
                   "retargeting (default: the built-in preset that fits, e.g. cesiumman, else found from the "
                   "skeleton's shape)" + ("; --joint-map is the same option" if alias else ""))
    if clip:
        g.add_argument("--clip-map", metavar="TOML|PRESET", help="joint map of the clip, for retargeting (default: "
                       "the built-in preset that fits, e.g. cmu, else found from the skeleton's shape)")


def glb_options(g) -> None:
    """--jiggle-bones and --max-influences, for `jiggle bake --formats glb` and `jiggle export --glb`."""
    g.add_argument("--jiggle-bones", type=count("--jiggle-bones", zero=True), metavar="N", help="jiggle bones in "
                   "the glb, spread over the muscles by how much they move (default: a bone per 64 skin vertices, at least 32, "
                   "at most 128 for the human and quadruped templates, else 2 per muscle)")
    g.add_argument("--max-influences", type=int, choices=[4, 8], default=4, help="skin weights per vertex in the "
                   "glb, the character's and the jiggle bones' together: 4 (JOINTS_0, which every engine reads) or "
                   "8 (default: 4)")


def bake_options(p: argparse.ArgumentParser, out: str) -> None:
    """Options shared by `jiggle bake` and `jiggle demo`."""
    p.add_argument("--out", default=out, help=f"output folder (default: {out})")
    p.add_argument("--resume", action="store_true", help="finish the interrupted bake in --out (same parameters)")
    bake_settings(p)


def bake_settings(p: argparse.ArgumentParser) -> None:
    """The bake's settings (time, jiggle, caches, skin) of `jiggle bake`, `demo` and `batch`."""
    from jiggle.sim.bake.scene import FORMATS
    g = p.add_argument_group("time")
    g.add_argument("--fps", type=positive("--fps"), metavar="N", help="output frames per second (default: the "
                   "scene's, else 30)")
    g.add_argument("--start", type=non_negative("--start"), metavar="S", help="first frame, seconds of the clip "
                   "(default: 0)")
    g.add_argument("--end", type=non_negative("--end"), metavar="E", help="last frame, seconds of the clip "
                   "(default: its end)")
    g.add_argument("--frames", type=count("--frames"), metavar="N", help="only the first N output frames")
    g.add_argument("--loop", choices=["auto", "on", "off"], default=None, help="a game cycle baked in its periodic "
                   "steady state: warmed up over repeated cycles, then one period written whose last frame repeats "
                   "the first (pose and jiggle), so it loops without a pop; auto: when the clip's last pose repeats its "
                   "first within 1%% of the character's height (root travel off), or the character's own animation "
                   "ends one key step before its start (default: auto)")
    g.add_argument("--drive", choices=["kinematic", "physics"], help="kinematic: MuJoCo poses the skeleton from the "
                   "clip; physics: MuJoCo simulates the body on a floor following it (default: the scene's, else "
                   "kinematic)")
    keyed_options(p)
    g = p.add_argument_group("jiggle solver (over the scene's [jiggle] section)")
    g.add_argument("--substeps", type=count("--substeps"), metavar="N", help="integration steps per output frame "
                   "(default: 4)")
    g.add_argument("--gravity", action="store_const", const=True, default=None, help="let the muscles sag under "
                   "gravity below their static shape (default: the scene's, else off)")
    g.add_argument("--preroll", type=non_negative("--preroll"), metavar="S", help="start at rest at the bind pose S "
                   "seconds early (default: the scene's, else 0: start settled on the first frame)")
    collision_option(g)
    g.add_argument("--device", metavar="NAME", help="the Warp device every kernel runs on: cpu, cuda or cuda:N "
                   "(default: cpu)")
    g = p.add_argument_group("caches")
    g.add_argument("--formats", metavar="LIST", help=f"comma-separated cache formats: {', '.join(FORMATS)} "
                   "(default: the scene's, else npz,usdc); glb: a skinned glTF with jiggle bones any engine plays "
                   "(the npz is written with it)")
    glb_options(g)
    g.add_argument("--chunk", type=count("--chunk"), metavar="N", help="frames per chunk written and resumed "
                   "(default: 64)")
    g = p.add_argument_group("skin")
    g.add_argument("--skinning", choices=["shell", "influence", "rbf"], help="how the muscles move the skin: shell, influence or rbf "
                   "(default: shell)")
    g.add_argument("--method", choices=["lbs", "dqs"], help="smooth skinning underneath (default: lbs)")
    g.add_argument("--mush", type=count("--mush", zero=True), metavar="N", help="Delta Mush clean-up of the "
                   "smooth skin, N smoothing steps (default: the scene's, else 0: off)")
    g.add_argument("--influences", type=count("--influences"), metavar="K", help="skin weights kept per vertex "
                   "(default: 4)")
    g.add_argument("--rigid", metavar="LIST", help="gear and hard shells that ride the body without jiggle: auto "
                   "(default: pieces bound rigidly to one joint, parts named like gear), none, or a comma-separated "
                   "list of parts (glTF node names) or joints to add, -NAME to leave soft (write --rigid=-NAME)")
    g.add_argument("--resolution", type=count("--resolution"), metavar="N",
                   help="generated body: target vertex count (default: the scene's, else 20000)")
    chain_options(p)
    for name in ("belly", "chest", "glutes", "upper-arms"):
        g.add_argument(f"--{name}", type=non_negative(f"--{name}"), metavar="M",
                       help=f"generated body: metres of fat on the {name.replace('-', ' ')}")


class KeyedAction(argparse.Action):
    """A keyable parameter's repeatable flag: ``[NAME=]VALUE`` with VALUE a number, keys ``[[t, v], ...]`` or
    ``smooth:[[t, v], ...]`` and NAME a muscle or a glob; appends (NAME or None, value, the flag as typed with
    its text, for messages). Without NAME: every muscle's (the global value when `global_ok`, else NAME "*").
    A bad value is a usage error (exit 2) naming the flag as typed (--jiggle or --strength)."""

    def __init__(self, option_strings, dest, parameter: str = "", global_ok: bool = True, table=None, **kw):
        self.parameter, self.global_ok, self.table = parameter, global_ok, table
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        from jiggle.rig.base.errors import InputError
        from jiggle.sim.jiggle.keyed import parse_assignment
        text = str(values).strip()
        try:
            pattern, value = parse_assignment(text, self.parameter, option_string, self.global_ok, self.table)
        except InputError as e:
            # argparse's style: the flag, then an entry NAME=VALUE named too
            parser.error(f"argument {option_string}: " + (e.message if "=" not in text else f"{text}: {e.message}"))
        items = list(getattr(namespace, self.dest, None) or [])
        items.append((pattern, value, f"{option_string} {text}"))
        setattr(namespace, self.dest, items)


KEYED_FLAGS = (("--strength", "strength", ("--jiggle",)), ("--frequency", "frequency", ()),
               ("--damping", "damping", ()), ("--goal-scale", "goal_scale", ()), ("--blend", "blend", ()))
"""The keyable parameters' flags: (flag, the parameter (sim.jiggle.keyed.PARAMETERS, the scene's key), aliases)."""


def keyed_options(p: argparse.ArgumentParser) -> None:
    """The keyable jiggle parameters (sim/jiggle/keyed.py), one repeatable flag each, in one group:
    --strength (alias --jiggle), --frequency, --damping, --goal-scale and --blend, each ``[NAME=]VALUE|CURVE``."""
    from jiggle.sim.jiggle.keyed import PARAMETERS
    g = p.add_argument_group(
        "jiggle parameters, keyable (over the scene's [jiggle] and [jiggle.muscles.NAME])",
        "Each flag is repeatable: [NAME=]VALUE, NAME a muscle or a glob (\"*_fat\", \"left_*\"; an exact name beats "
        "a glob, a later glob an earlier one; a glob matching no muscle is an error), VALUE a number or keys "
        "[[t_s,v],...] (linear; smooth:[[t_s,v],...] for a monotone cubic). Without NAME: every muscle.")
    g.add_argument("--material", dest="material", action="append", metavar="[NAME=]MATERIAL",
                   help="a muscle's (or a glob's; every muscle's without NAME) tissue material in physical units: fat, "
                        "muscle, or E=PA,nu=...,rho=KG_M3,zeta=... (E takes kPa / MPa too; keys left out keep the "
                        "muscle material's); its goal springs, damping and density follow from the material and the "
                        "muscle's size (sim/jiggle/materials.py); --frequency and --damping still override it")
    for flag, name, aliases in KEYED_FLAGS:
        par = PARAMETERS[name]
        unit = f" {par.unit}" if par.unit else ""
        dest = "jiggle" if name == "strength" else name
        g.add_argument(flag, *aliases, dest=dest, action=KeyedAction, metavar="[NAME=]VALUE", parameter=name,
                       global_ok=name in ("strength", "blend"),
                       help=f"{par.what}; in {par.range_text}{unit} (default: {par.default})"
                       + ("; --jiggle is the same flag" if aliases else ""))


def keyed_request(args) -> dict:
    """BakeRequest fields from the keyable flags: jiggle (the last global --strength), blend (the last
    global --blend) and muscles, the NAME=VALUE entries (pattern, {scene key: value}, flag text) in order."""
    out = {"jiggle": None, "blend": None, "muscles": []}
    for _, name, _ in KEYED_FLAGS:
        dest = "jiggle" if name == "strength" else name
        for pattern, value, text in getattr(args, dest, None) or []:
            if pattern is None:
                out[dest] = value
            else:
                out["muscles"].append((pattern, {name: value}, text))
    out["muscles"] = tuple(out["muscles"])
    out["materials"] = tuple(getattr(args, "material", None) or ())
    return out


CHAIN_FLAGS = (("--chain-stiffness", "stiffness"), ("--chain-damping", "damping"), ("--chain-gravity", "gravity"),
               ("--chain-drag", "drag"))
"""The chains' keyable parameters' flags: (flag, sim.chain.params.CHAIN_PARAMETERS name, the scene's key)."""


def chain_options(p: argparse.ArgumentParser) -> None:
    """--chains and the chains' keyable parameters (sim/chain): tails, ears, hair and wing fingers that swing."""
    from jiggle.sim.chain.params import CHAIN_PARAMETERS
    g = p.add_argument_group(
        "chains: tails, ears, hair, wing fingers that swing (over the scene's [chains] and [chains.NAME])",
        "Each parameter flag is repeatable: [NAME=]VALUE, NAME a chain (its root joint's name, as `jiggle inspect` "
        "lists them) or a glob (\"Tail*\", \"Ear*\"); VALUE a number or keys [[t_s,v],...]. Without NAME: every chain.")
    g.add_argument("--chains", metavar="LIST", help="which chains swing: auto (default: appendages found by name and "
                   "shape, and a glTF's VRM spring bones), none, or a comma-separated list of joints or globs that "
                   "start one (with auto in it, added to the ones found; -NAME drops one: write --chains=-NAME)")
    for flag, name in CHAIN_FLAGS:
        par = CHAIN_PARAMETERS[name]
        unit = f" {par.unit}" if par.unit else ""
        g.add_argument(flag, dest="chain_" + name, action=KeyedAction, metavar="[NAME=]VALUE", parameter=name,
                       global_ok=False, table=CHAIN_PARAMETERS,
                       help=f"{par.what}; in {par.range_text}{unit} (default: {par.default})")


def chain_request(args) -> dict:
    """BakeRequest fields from --chains and the chain parameter flags: chains (the mode) and chain_params, the
    NAME=VALUE entries (pattern, {parameter: value}, flag text) in the order given."""
    entries = []
    for _, name in CHAIN_FLAGS:
        for pattern, value, text in getattr(args, "chain_" + name, None) or []:
            entries.append((pattern or "*", {name: value}, text))
    return {"chains": getattr(args, "chains", None), "chain_params": tuple(entries)}


def collision_option(g) -> None:
    """--collisions / --no-collisions: the particles collide with other body parts' bone capsules and the floor."""
    from jiggle.sim.jiggle.params import COLLIDERS, JiggleSettings
    g.add_argument("--collisions", action=argparse.BooleanOptionalAction, default=None,
                   help="the muscles' particles collide with the bone capsules of other body parts and with the floor "
                   f"(default: the scene's, else {'on' if JiggleSettings().collisions else 'off'})")
    g.add_argument("--colliders", choices=COLLIDERS, default=None,
                   help="the capsules they collide with: bone (fitted inside the character's skin around each bone) or "
                   "model (the MuJoCo model's own capsule geoms, kept inside the skin) (default: the scene's, else "
                   f"{JiggleSettings().colliders})")
    g.add_argument("--muscle-collisions", action=argparse.BooleanOptionalAction, default=None,
                   help="the particles of muscles of different body parts collide with each other too (slower: one "
                   "launch per step) (default: the scene's, else off)")


def template_option(g) -> None:
    """--template: the muscle template that commands fitting muscles to a character take."""
    g.add_argument("--template", metavar="T", help="muscle template: auto, a built-in name (human, quadruped), "
                   "generic (tissue on any body, from the skin's segmentation by bone) or .toml/.xml (default: auto: "
                   "human or quadruped by the skeleton's body plan, generic where neither fits)")


def muscle_skin_options(g) -> None:
    """--skinning, --method, --mush: how the muscles move the skin, over which smooth skinning."""
    g.add_argument("--skinning", choices=["shell", "influence", "rbf"], default="shell",
                   help="how the muscles move the skin: shell deformers, influence objects or anatomy-driven RBF "
                   "(default: shell)")
    g.add_argument("--method", choices=["lbs", "dqs"], default="lbs", help="smooth skinning underneath (default: lbs)")
    g.add_argument("--mush", type=count("--mush", zero=True), default=0, metavar="N", help="Delta Mush clean-up of "
                   "the smooth skin, N smoothing steps (default: 0, off)")


def influences_option(g) -> None:
    """--influences: skin weights kept per vertex when a character is read or weighted."""
    g.add_argument("--influences", type=count("--influences"), default=4, metavar="K",
                   help="skin weights kept per vertex (default: 4)")
