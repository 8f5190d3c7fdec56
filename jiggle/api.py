"""jiggle's public Python API: bake a clip on a character, read a bake, compare, export; or drive the pipeline a
stage at a time. Everything here is re-exported by the package (`jiggle.bake`, `jiggle.Bake`, ...).

One code path with the command line: `bake` and the `Bake` methods run the `jiggle` command's own subcommands
(`bake`, `compare`, `export`, `view`), their keyword arguments turned into the command's options and parsed by its
own parser, so the defaults, the checks and the messages are the command's. A user's mistake raises
`InputError` with the message the command prints after "jiggle: error:".

Shapes: T frames, V skin vertices, F triangles, J joints, M muscles, N muscle control points in all. Lengths are
metres, times seconds.
"""
from __future__ import annotations

import contextlib
import functools
import io
import json
import os
import shutil
import tempfile
import weakref
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np

from jiggle.rig.base.errors import InputError
from jiggle.rig.muscle.material import FAT, MUSCLE, Material
from jiggle.rig.character.character import Character
from jiggle.rig.motion.clip import Clip
from jiggle.rig.muscle.fit import Musculature

Muscles = Musculature
"""What `fit` returns: the character's muscles and fat fitted from a template (rig.muscle.fit.Musculature)."""

__all__ = ["bake", "Bake", "Metrics", "InputError", "load_character", "load_clip", "fit", "simulate", "Muscles",
           "Simulation", "Character", "Clip", "Material", "FAT", "MUSCLE"]


def _argv(command: str, positional: list, options: dict) -> list[str]:
    """The command line of `command` for keyword options: name -> --name (underscores as dashes); True -> the
    flag, False -> its --no- form (or nothing where there is none), None -> left out, a list -> comma-separated;
    `muscles` -> one NAME=VALUE flag per muscle and parameter. Unknown names are a TypeError, as Python's own."""
    sub = _subparser(_parser(), command)
    flags = {s: a for a in sub._actions for s in a.option_strings}
    argv = [command] + [str(p) for p in positional if p is not None]
    for name, value in options.items():
        if value is None:
            continue
        if name == "muscles":
            argv += _muscle_flags(value, flags)
            continue
        if name == "chain_params":
            argv += _chain_flags(value)
            continue
        if name == "materials":
            argv += _material_flags(value)
            continue
        flag = "--" + name.replace("_", "-")
        if flag not in flags:
            raise TypeError(f"{command}() got an unexpected keyword argument {name!r}")
        action = flags[flag]
        if value is True or value is False:
            no = "--no-" + name.replace("_", "-")
            if value:
                argv.append(flag)
            elif no in flags:
                argv.append(no)
            continue
        if isinstance(value, (list, tuple)):
            value = ",".join(str(v) for v in value)
        argv += [flag, _text(value)] if action.nargs != 0 else [flag]
    return argv


def _material_flags(materials) -> list[str]:
    """{"*_fat": "fat", "belly*": Material(...) or {"E": 3e3, "zeta": 0.2}} -> ["--material", "*_fat=fat", ...]: each
    muscle's (or glob's) tissue material (rig.muscle.material): a name, a Material or its keys E, nu, rho, zeta."""
    from jiggle.rig.muscle.material import KEYS, Material
    if not hasattr(materials, "items"):
        raise InputError(f"must map a muscle (or glob) to a material, e.g. {{'*_fat': 'fat'}}, got {materials!r}",
                         field="materials")
    out = []
    for pattern, m in materials.items():
        if isinstance(m, Material):
            m = {k: getattr(m, a) for k, a in KEYS.items()}
        if hasattr(m, "items"):
            m = ",".join(f"{k}={v!r}" if not isinstance(v, str) else f"{k}={v}" for k, v in m.items())
        out += ["--material", f"{pattern}={m}"]
    return out


def _chain_flags(chains) -> list[str]:
    """{"Tail*": {"stiffness": 3}} -> ["--chain-stiffness", "Tail*=3"]: a chain's (or glob's) keyable parameters."""
    from jiggle.sim.chain.params import CHAIN_PARAMETERS
    if not hasattr(chains, "items"):
        raise InputError(f"must map a chain (or glob) to its parameters, e.g. {{'Tail*': {{'stiffness': 3}}}}, got "
                         f"{chains!r}", field="chain_params")
    out = []
    for pattern, params in chains.items():
        if not hasattr(params, "items"):
            raise InputError(f"[{pattern!r}] must map parameters to values, e.g. {{'damping': 0.5}}, got {params!r}",
                             field="chain_params")
        for key, value in params.items():
            if key not in CHAIN_PARAMETERS:
                raise InputError(f"[{pattern!r}] unknown chain parameter {key!r}; the parameters are "
                                 f"{', '.join(CHAIN_PARAMETERS)}", field="chain_params")
            out += [f"--chain-{key}", f"{pattern}={_text(value)}"]
    return out


def _muscle_flags(muscles, flags: dict) -> list[str]:
    """{"belly_fat": {"strength": 0.5}} -> ["--strength", "belly_fat=0.5"]: a muscle's (or glob's) keyable
    parameters, in the order given."""
    if not hasattr(muscles, "items"):
        raise InputError(f"must map a muscle name (or glob) to its parameters, e.g. "
                         f"{{'belly_fat': {{'strength': 0.5}}}}, got {muscles!r}", field="muscles")
    from jiggle.sim.app.args import KeyedAction
    keyed = {f: a for f, a in flags.items() if isinstance(a, KeyedAction) and a.table is None}   # not the chains'
    out = []
    for pattern, params in muscles.items():
        if not hasattr(params, "items"):
            raise InputError(f"[{pattern!r}] must map parameters to values, e.g. {{'strength': 0.5}}, got "
                             f"{params!r}", field="muscles")
        for key, value in params.items():
            flag = "--" + str(key).replace("_", "-")
            if flag not in keyed:
                names = sorted(f[2:].replace("-", "_") for f in keyed if f != "--jiggle")
                raise InputError(f"[{pattern!r}]: unknown parameter {key!r}; a muscle takes {', '.join(names)}",
                                 field="muscles")
            out += [flag, f"{pattern}={_text(value)}"]
    return out


def _text(value) -> str:
    """A value as the command line writes it (floats exactly: repr round-trips)."""
    return repr(value) if isinstance(value, float) else os.fspath(value) if isinstance(value, os.PathLike) \
        else str(value)


@functools.lru_cache(maxsize=1)
def _parser():
    """The `jiggle` command's parser (built once: parsing does not change it)."""
    from jiggle.sim.app.cli import build_parser
    return build_parser()


def _subparser(parser, command: str):
    for a in parser._actions:
        if getattr(a, "choices", None) and command in a.choices:
            return a.choices[command]
    raise KeyError(command)


def _parse(argv: list[str]):
    """The command's arguments, its parser's errors raised as InputError (the message it would print)."""
    from jiggle.sim.app.args import raising_errors
    with raising_errors():
        return _parser().parse_args(argv)


@contextlib.contextmanager
def _quiet_warp():
    """Warp's start-up banner and kernel-load lines hidden, as the command hides them."""
    from jiggle.sim.app.cli import warp_output
    with warp_output(verbose=False, quiet=False):
        yield


def _run(argv: list[str], quiet: bool = True):
    """Run a subcommand as `jiggle` runs it (its stdout, the list of files written, kept when not quiet)."""
    args = _parse(argv)
    sink = io.StringIO()
    with _quiet_warp(), (contextlib.redirect_stdout(sink) if quiet else contextlib.nullcontext()):
        args.func(args)
    return args


def bake(clip: str | os.PathLike | None = None, character: str | os.PathLike | None = None, *,
         out: str | os.PathLike | None = None, scene: str | os.PathLike | None = None, template: str | None = None,
         fps: float | None = None, strength: float | str | None = None, blend: float | str | None = None,
         muscles: dict | None = None, materials: dict | None = None, collisions: bool | None = None,
         device: str | None = None, formats: str | list | None = None, progress: bool = True, **options) -> "Bake":
    """Bake a clip on a character: `jiggle bake` from Python, with the same defaults, checks and result.

    Parameters
    ----------
    clip : str or PathLike, optional
        The motion: BVH, ASF/AMC, glTF/GLB with animations, or FBX. None: the scene's, else the built-in demo.
    character : str or PathLike, optional
        A skinned glTF/GLB or FBX the clip is retargeted onto. None: the scene's, else a body generated around
        the clip's skeleton (a glTF character without a clip bakes its own animation).
    out : str or PathLike, optional
        The folder to write (bake.json, bake.npz and the other formats). None: a temporary folder, removed when
        the returned Bake is garbage collected.
    scene : str or PathLike, optional
        A scene TOML (Reference: scene files); the keyword arguments override it.
    template : str, optional
        The muscle template: "auto" (human or quadruped by the skeleton's body plan), "human", "quadruped" or a
        .toml/.xml file.
    fps : float, optional
        Output frames per second (default: the scene's, else 30).
    strength, blend : float or str, optional
        Every muscle's jiggle strength and static/dynamic blend: a number, or keys as the command line writes
        them ("0:1,2:0.2", seconds:value).
    muscles : dict, optional
        Per muscle (a name or a glob) keyable parameters: strength, frequency (Hz), damping, goal_scale, blend;
        e.g. ``{"belly_fat": {"strength": 0.5}, "*_deltoid": {"damping": 0.3}}``.
    materials : dict, optional
        Per muscle (a name or a glob) tissue material in physical units: "fat", "muscle", a
        jiggle.rig.muscle.material.Material, or its keys ``{"E": 3e3, "nu": 0.49, "rho": 920, "zeta": 0.3}`` (Pa,
        kg/m^3); the goal springs follow from it and the muscle's size, and `muscles` frequency / damping still
        override it. E.g. ``{"*_fat": "fat", "belly*": {"E": 2e3}}``.
    collisions : bool, optional
        The particles collide with the bone capsules of other body parts and with the floor.
    device : str, optional
        The Warp device: "cpu", "cuda" or "cuda:N" (default "cpu").
    formats : str or list of str, optional
        Cache formats: "npz", "usd", "usda", "pc2", "glb" (default npz and usd). npz is always written: Bake reads
        it.
    progress : bool
        A progress bar on stderr.
    **options
        Any other `jiggle bake` option by its name: substeps=4, frames=30, drive="physics", skinning="rbf",
        jiggle_bones=64, ... (`jiggle bake --help`, or Reference: command line).

    Returns
    -------
    Bake
        The finished bake, read from `out`.

    Raises
    ------
    InputError
        A mistake in the inputs (a missing file, a bad value), with the message `jiggle bake` prints.
    TypeError
        A keyword that is no option of `jiggle bake`.
    """
    from jiggle.sim.app.commands.bake import bake_request, run_bake
    if formats is not None:
        formats = [formats] if isinstance(formats, str) else list(formats)
        formats = ",".join(dict.fromkeys([*",".join(formats).split(","), "npz"]))
    folder = tempfile.mkdtemp(prefix="jiggle-bake-") if out is None else os.fspath(out)
    try:
        args = _parse(_argv("bake", [scene], {"clip": clip, "character": character, "out": folder,
                                               "template": template, "fps": fps, "strength": strength,
                                               "blend": blend, "muscles": muscles, "materials": materials,
                                               "collisions": collisions,
                                               "device": device, "formats": formats, **options}))
        with _quiet_warp():
            run_bake(bake_request(args), args.out, resume=args.resume, progress="bar" if progress else "none")
    except BaseException:
        if out is None:
            shutil.rmtree(folder, ignore_errors=True)
        raise
    result = Bake.open(folder)
    if out is None:
        weakref.finalize(result, shutil.rmtree, folder, True)
    return result


@dataclass(frozen=True)
class Metrics:
    """What `jiggle compare` measured (its metrics.json), with the folder its plots, renders and report are in.

    data : the whole metrics.json, read-only. report : report.html's path (None without renders).
    The most asked-for figures are properties; every other one is in `data`.
    """

    folder: Path
    data: MappingProxyType

    @property
    def report(self) -> Path | None:
        p = self.folder / "report.html"
        return p if p.is_file() else None

    def __getitem__(self, key):
        return self.data[key]

    def keys(self):
        return self.data.keys()


class Bake:
    """A finished bake, read from its folder (bake.json and bake.npz). The arrays are read-only NumPy arrays:

    skin_static, skin_final, skin_lbs : (T, V, 3) float32 the skin with the static muscles, with the muscles'
        jiggle blended in (the result), and the plain smooth skin. skin_rest : (V, 3). faces : (F, 3) int32.
    times : (T,) seconds of the clip. fps : frames per second. joint_names : (J,). joint_world : (T, J, 4, 4) the
        clip's joints' world transforms. muscle_names : (M,). muscle_cvs_static, muscle_cvs_dynamic : (T, N, 3) the
        muscles' control points, muscle m's rows muscle_cv_offsets[m]:muscle_cv_offsets[m + 1]. activation : (T, M)
        each muscle's activation, 0 to 1 (a bake with activation="on" only).
    params : the bake's full parameter set (bake.json "params"); summary : the whole bake.json.
    """

    ARRAYS = ("skin_static", "skin_final", "skin_lbs", "skin_rest", "faces", "times", "joint_names", "joint_world",
              "muscle_names", "muscle_cvs_static", "muscle_cvs_dynamic", "muscle_cv_offsets", "muscle_faces",
              "activation")

    def __init__(self, folder: Path, summary: dict, arrays: dict):
        self.folder, self.summary, self._arrays = folder, summary, arrays

    @classmethod
    def open(cls, folder: str | os.PathLike) -> "Bake":
        """Read the bake in `folder` (written by `jiggle bake --out folder` or `jiggle.bake(out=folder)`)."""
        folder = Path(folder)
        if not (folder / "bake.json").is_file():
            raise InputError("not a finished bake (no bake.json): bake it first with `jiggle bake --out FOLDER`",
                             str(folder))
        if not (folder / "bake.npz").is_file():
            raise InputError("the bake has no bake.npz: bake again with --formats npz", str(folder))
        summary = json.loads((folder / "bake.json").read_text(encoding="utf-8"))
        with np.load(folder / "bake.npz", allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files if k in cls.ARRAYS}
        for a in arrays.values():
            a.flags.writeable = False
        return cls(folder, summary, arrays)

    def __getattr__(self, name):
        if name in Bake.ARRAYS:
            arrays = self.__dict__.get("_arrays", {})
            if name in arrays:
                return arrays[name]
            raise AttributeError(f"this bake has no {name} (an older bake?)")
        raise AttributeError(f"'Bake' object has no attribute {name!r}")

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(self._arrays))

    def __repr__(self):
        s = self.summary
        return (f"<jiggle.Bake {s.get('name')!r}: {s.get('frames')} frames at {s.get('fps')} fps, {s.get('vertices')} "
                f"vertices, {s.get('muscles')} muscles in {str(self.folder)!r}>")

    @property
    def fps(self) -> float:
        return float(self.summary["fps"])

    @property
    def params(self) -> dict:
        return self.summary.get("params", {})

    def muscle(self, name: str, which: str = "dynamic") -> np.ndarray:
        """(T, n, 3) one muscle's control points ("static" or "dynamic"); `name` as in muscle_names."""
        names = [str(n) for n in self.muscle_names]
        if name not in names:
            raise InputError(f"no muscle {name!r}; this bake has {', '.join(names)}", field="name")
        m = names.index(name)
        o = self.muscle_cv_offsets
        return getattr(self, f"muscle_cvs_{which}")[:, o[m]:o[m + 1]]

    def compare(self, *, render: bool = True, video: bool = False) -> Metrics:
        """`jiggle compare` on this bake: static against dynamic in numbers, plots, renders and report.html, written
        into the bake's folder; returns its metrics."""
        _run(["compare", str(self.folder)] + ([] if render else ["--no-render"]) + ([] if video else ["--no-video"]))
        data = json.loads((self.folder / "metrics.json").read_text(encoding="utf-8"))
        return Metrics(self.folder, MappingProxyType(data))

    def to_glb(self, path: str | os.PathLike, *, jiggle_bones: int | None = None, max_influences: int = 4) -> Path:
        """`jiggle export --glb`: the bake as a skinned glTF with jiggle bones any engine plays."""
        return self._export("glb", path, jiggle_bones=jiggle_bones, max_influences=max_influences)

    def to_usd(self, path: str | os.PathLike) -> Path:
        """`jiggle export --usd`: the bake as a USD stage (.usd/.usdc binary, .usda text)."""
        return self._export("usd", path)

    def to_pc2(self, path: str | os.PathLike) -> Path:
        """`jiggle export --pc2`: skin_final as a PC2 point cache."""
        return self._export("pc2", path)

    def _export(self, form: str, path, **options) -> Path:
        _run(_argv("export", [self.folder], {form: os.fspath(path), **options}))
        return Path(path)

    def view(self, *, port: int = 8080, host: str = "127.0.0.1") -> None:
        """`jiggle view`: play the bake in the browser (viser), until interrupted."""
        _run(_argv("view", [self.folder], {"port": port, "host": host}), quiet=False)


def load_character(path: str | os.PathLike, *, influences: int = 4, unit: str | float | None = None,
                   skin: int = 0) -> Character:
    """Read a skinned character, the first stage of a pipeline of one's own.

    Parameters
    ----------
    path : str or PathLike
        A skinned glTF/GLB or FBX (6.1/7.x, binary or ASCII).
    influences : int
        Joint influences kept per vertex.
    unit : str or float, optional
        Metres per file unit ("m", "cm", "mm", "in", "ft" or a number). None: metres unless the height says
        centimetres or millimetres.
    skin : int
        Which skin of a glTF with several.

    Returns
    -------
    Character
        Rest skin vertices (V, 3) metres, faces (F, 3), joints and weights (V, k), the skeleton's bind.
    """
    from dataclasses import replace

    from jiggle.rig.character.load import load_character as load
    with _quiet_warp():
        c = load(path, k=influences, unit=unit, skin=skin)
    return replace(c, meta={**c.meta, "file": os.path.abspath(path)})      # `simulate` retargets onto it


def load_clip(path: str | os.PathLike, *, animation: str | int | None = None, scale: float | None = None,
              skeleton: str | os.PathLike | None = None) -> Clip:
    """Read a motion clip.

    Parameters
    ----------
    path : str or PathLike
        BVH, ASF/AMC, glTF/GLB with animations, or FBX with takes.
    animation : str or int, optional
        A glTF's or FBX's animation by name or index (default: the first).
    scale : float, optional
        Metres per BVH unit (None: CMU recognised, else guessed from the height).
    skeleton : str or PathLike, optional
        An AMC's ASF, when it is not the one beside it.

    Returns
    -------
    Clip
        Joint names, parents, rest offsets, and per frame the root position (m) and joint rotations, at the
        clip's frame rate.
    """
    from jiggle.rig.motion.mocap import load_clip as load
    return load(path, skeleton=skeleton, animation=animation, scale=scale)


def fit(character: Character, template: str = "auto") -> Muscles:
    """Fit muscles and fat to a character's skin from the outside in (`jiggle fit`).

    Parameters
    ----------
    character : Character
        From `load_character`.
    template : str
        "auto" (human or quadruped by the skeleton's body plan), "human", "quadruped", or a .toml/.xml file.

    Returns
    -------
    Muscles
        The fitted musculature: ``.rig`` (the muscle rig: M muscles, their control points), ``.muscles``,
        ``.plan`` (the body plan found) and ``.template``.
    """
    from jiggle.rig.muscle.fit import FitOptions, fit_musculature
    with _quiet_warp():
        return fit_musculature(character, template, FitOptions())


@dataclass(frozen=True)
class Simulation:
    """What `simulate` made, in memory: the arrays of a bake (see Bake) of a clip on a character with given
    muscles. skin_static, skin_final, skin_lbs : (T, V, 3) float32; times : (T,); muscle_cvs_static,
    muscle_cvs_dynamic : (T, N, 3); params : the parameter set; data : the whole rig/sim BakeData."""

    skin_static: np.ndarray
    skin_final: np.ndarray
    skin_lbs: np.ndarray
    times: np.ndarray
    muscle_cvs_static: np.ndarray
    muscle_cvs_dynamic: np.ndarray
    params: dict
    data: object


def simulate(clip: Clip, character: Character, muscles: Muscles | None = None, *, fps: float | None = None,
             strength: float | None = None, blend: float | None = None, collisions: bool | None = None,
             frames: int | None = None, device: str | None = None, character_file: str | None = None) -> Simulation:
    """Move the skeleton by the clip, shape the static muscles, simulate their jiggle and deform the skin, for a
    clip, a character and muscles of one's own; `bake` is the same pipeline from files, with every option.

    Parameters
    ----------
    clip : Clip
        From `load_clip`; retargeted onto the character's file (`character_file`, else the one
        `load_character` read). A character without a file needs a clip on its own skeleton.
    character : Character
        From `load_character`.
    muscles : Muscles, optional
        From `fit`; None: fitted with the template "auto".
    fps : float, optional
        Output frames per second (default 30).
    strength, blend : float, optional
        Every muscle's jiggle strength and static/dynamic blend.
    collisions : bool, optional
        The particles collide with the bone capsules and the floor.
    frames : int, optional
        Only the first N output frames.
    device : str, optional
        The Warp device ("cpu", "cuda").
    character_file : str, optional
        The character's glTF/FBX, to retarget the clip onto.

    Returns
    -------
    Simulation
        The bake's arrays in memory.
    """
    from jiggle.sim.bake.baker import bake_in_memory
    from jiggle.sim.bake.setup import BakeRequest, prepare_from
    with _quiet_warp():
        setup = prepare_from(clip, character, muscles, BakeRequest(fps=fps, jiggle=strength, blend=blend,
                                                                   collisions=collisions, frames=frames,
                                                                   device=device),
                             character_file=character_file or character.meta.get("file"))
        data = bake_in_memory(setup)
    ro = {}
    for k in ("skin_static", "skin_final", "skin_lbs", "muscle_cvs_static", "muscle_cvs_dynamic"):
        ro[k] = np.asarray(getattr(data, k))
        ro[k].flags.writeable = False
    times = np.asarray(setup.times)
    return Simulation(times=times, params=setup.params, data=data, **ro)
