"""Musculoskeletal templates (Pratscher et al. 2005, section 3.4, Figure 5).

A template stores, for each muscle or muscle pair, where it sits and how it attaches, never its
geometry: the bone whose skin region it is fitted to (parent and child joint labels), the pair's
partition plane, and per muscle its name, pair id and type, the four attachment points (origin,
origin hinge, insertion hinge, insertion) each with the bone it rides and an optional position,
the part of the bone's region it takes (span along the bone, sector around it), section scales,
shaping parameters and default jiggle parameters. The geometry is made again for every character
by fitting and conforming to its skin, so one template serves characters of any shape.

Labels are roles (:data:`rig.motion.retarget.ROLES`: ``hips``, ``spine``, ``chest``, ``left_upper_arm``,
...; for four-legged templates :data:`rig.motion.body_plan.QUADRUPED_ROLES`: ``left_front_upper_leg``,
``tail``, ...), not joint names: a skeleton's role map (``rig.motion.role_map.resolve_roles``, from a joint map
preset, a user's joint map or the automatic one) turns them into joints, so one template serves
naming schemes as different as CMU's and CesiumMan's. :func:`check_labels` says which labels a
skeleton lacks.

Two file forms hold the same template, and each converts to the other without loss:

XML, the paper's layout (``.xml``)::

    <musculoskeletalTemplate name="human">
      <boneMusclePair>
        <bone><parentJoint>left_upper_arm</parentJoint><childJoint>left_lower_arm</childJoint></bone>
        <partition angle="0.0"/>
        <muscle pairId="0" type="upper" kind="muscle">
          <name>left_biceps</name>
          <origin><parentJoint>left_upper_arm</parentJoint>
                  <position type="relative" x="0.0" y="0.0" z="0.0"/></origin>
          <oHinge/> <iHinge/> <insertion>...</insertion>
          <span t0="0.25" t1="1.0"/>  <sector a0="-60" a1="60"/>
          <sections rim="1" bulge="1" main="1" bulgePosition="0.25"/>
          <shape tone="1" nu="3" thicknessMin="0.004" depth="0.03" count="1"/>
          <jiggle material="muscle" goalTendon="0.9" goalBelly="0.4"
                  strength="1" springFrequency="7" springDamping="0.3" friction="0"/>
          <shell sticky="1" hard="0.5" dropOff="1" weight="1" slippage="1" mode="stretch"/>
        </muscle>
      </boneMusclePair>
    </musculoskeletalTemplate>

A file whose root is a single ``<boneMusclePair>`` (as in the paper's Figure 5) is read as a
template of one pair. Files are parsed with defusedxml and DTDs are refused, so entity expansion
("billion laughs") and external entities never run.

TOML (``.toml``)::

    name = "human"
    [[pair]]
    bone = ["left_upper_arm", "left_lower_arm"]
    partition = 0.0
    [[pair.muscle]]
    name = "left_biceps"
    pair_id = 0
    type = "upper"
    insertion = { parent_joint = "left_lower_arm", position = { type = "relative", x = 1.12, y = 0.08, z = 0.0 } }
    span = [0.25, 1.0]
    tone = 1.0
    jiggle = { material = "muscle", goal_tendon = 0.9, goal_belly = 0.4 }
    shell = { sticky = 1.0, hard = 0.5, drop_off = 1.0, weight = 1.0, slippage = 1.0, mode = "stretch" }

Everything but the bone and a muscle's name is optional; a missing value takes its default (the
jiggle and shell defaults depend on the kind; a partial ``jiggle`` or ``shell`` table takes the rest
of its values from the kind's default). Writers write every value that is set, so a file read back
gives an equal :class:`Template`. Unknown elements, attributes and keys are errors (a typo must not
pass silently), and every number is checked against its range; errors name the file, the field
(``pair[3].muscle[1].tone``, in the TOML spelling for both forms) and, in XML, the line.

Meaning of the fields (the bone frame is the one in the project's muscle contract: e_along from the
bone's start to its end, e_front the character's front made perpendicular, e_side = e_along x
e_front; angles about the bone go from e_front toward e_side, degrees):

- reference (per pair, TOML ``reference``, XML ``<partition reference=...>``) : "front" (default)
  or "up": the world direction e_front is made from. A quadruped's spine, neck and tail point along
  its front, so their pairs say "up": e_front is then the back (dorsal) side, e_side = e_along x up.
- partition : the plane through the bone segment's centre that splits its region into the pair's
  two muscles; its normal is at this angle (0: normal along e_front, a front/back split). The
  ``upper`` muscle takes the side the normal points to, ``lower`` the other; ``single`` muscles
  ignore the plane.
- span (t0, t1) : fraction along the bone of the sub-region the muscle takes (t0 < t1; may reach
  past the ends, e.g. a deltoid starting above the shoulder joint). sector (a0, a1) : angles about
  the bone it takes (a0 < a1 <= a0 + 360), or None for all around.
- attachments : ``joint`` is the role label of the bone the point rides (None: origin rides the
  pair's parent joint, insertion its child joint, the hinges the parent joint); ``position`` is
  ``relative``: start + L (x e_along + y e_front + z e_side) in the muscle's bone frame at bind (L
  the bone's length), or ``absolute``: world metres at bind (character specific, as in the paper's
  Figure 5); None: origin at the bone's start, insertion at its end, hinges at the ends of the
  fitted muscle's major axis.
- rim_scale, bulge_scale, main_scale : scales of the fitted muscle's rim, bulge and main
  cross-sections; bulge_position : where the bulge sections sit, as a fraction of the belly from
  each end (0..0.5); tone : 0..1, how strongly the volume rule thickens the muscle.
- nu : the conforming attenuation of section 3.3; thickness_min : metres, thinnest fitted radius;
  depth : metres, fat only: thickness of the fat layer under the skin (the fitted fat is at least
  this thick; default FAT_DEPTH for fat, 0 for muscles, which use thickness_min).
- kind : ``muscle``, ``fat`` (soft tissue that jiggles, no tendons to speak of) or ``multi_belly``
  (``count`` bellies in a row along the span, like the rectus abdominis).
- jiggle : default particle parameters for the simulation (:class:`Jiggle`: the part's material, frequency Hz
  and damping ratio of the goal springs, goal weights at the tendons and the belly, density kg/m^3, jiggle
  strength 0..1, neighbour springs' frequency Hz and damping ratio, friction 1/s). The material (``fat``,
  ``muscle`` or ``E=...,nu=...,rho=...,zeta=...``; default the kind's: rig/muscle/material.py, with its
  sources) sets the goal springs' frequency and damping and the density at the character's real size
  (sim/jiggle/materials.py); a ``frequency``, ``damping`` or ``density`` the template gives is used as
  given instead (the template's own tuning; bake.json says which set them).
- shell : the muscle's skin deformer (:class:`rig.muscle.shell_params.ShellParams`: sticky s, hard h, drop_off d
  in local units of the muscle's radius, weight w, slippage l, mode basic/stretch/trajectory);
  default :func:`rig.muscle.shell_params.default_shell` of the kind. The per-vertex painted weights are not part
  of the template (they belong to a character: rig/skin/shell/weights.py).
"""
from __future__ import annotations

import importlib.resources
import math
import os
import re
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field, fields

from defusedxml.common import DefusedXmlException, DTDForbidden, EntitiesForbidden, ExternalReferenceForbidden
from defusedxml.ElementTree import DefusedXMLParser

from jiggle.rig.base.atomic import atomic_path
from jiggle.rig.base.errors import InputError, require_file
from jiggle.rig.motion.body_plan import QUADRUPED_REQUIRED, QUADRUPED_ROLES
from jiggle.rig.motion.retarget import REQUIRED, ROLES
from jiggle.rig.muscle.shell_params import ShellParams, check_params, default_shell

LABELS = ROLES + tuple(r for r in QUADRUPED_ROLES if r not in ROLES)
"""Template labels: the human roles (rig.motion.retarget.ROLES) and the quadruped ones
(rig.motion.body_plan.QUADRUPED_ROLES)."""
OPTIONAL_ROLES = tuple(r for r in LABELS if r not in REQUIRED and r not in QUADRUPED_REQUIRED)
"""Roles a skeleton may lack (a collar bone, a toe, a tail, a neck joint): a template pair that needs
one the skeleton does not have is left out with a notice (rig.muscle.fit), not refused."""
REFERENCES = ("front", "up")
TYPES = ("upper", "lower", "single")
KINDS = ("muscle", "fat", "multi_belly")
POSITION_TYPES = ("relative", "absolute")
ATTACHMENTS = ("origin", "o_hinge", "i_hinge", "insertion")
SUFFIXES = (".toml", ".xml")
MAX_BELLIES = 8

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_.\-]*\Z")


# ----------------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class Position:
    """An attachment point's place at bind.

    type : "relative": xyz = (x, y, z) in bone lengths in the muscle's bone frame, the point being
        start + L (x e_along + y e_front + z e_side); "absolute": xyz in world metres.
    xyz : (3,) floats.
    """

    type: str
    xyz: tuple[float, float, float]

    def __post_init__(self):
        object.__setattr__(self, "xyz", tuple(float(v) for v in self.xyz))


@dataclass(frozen=True)
class Attachment:
    """One of a muscle's four attachment points.

    joint : role label of the bone the point rides, or None for the default (origin: the pair's
        parent joint; insertion: its child joint; hinges: its parent joint).
    position : where it is at bind, or None for the default (origin: the bone's start; insertion:
        the bone's end; hinges: the ends of the fitted muscle's major axis).
    """

    joint: str | None = None
    position: Position | None = None


@dataclass(frozen=True)
class Jiggle:
    """Default simulation parameters of one muscle (sim/jiggle/params.py explains the model).

    material : what the part is made of: "fat", "muscle" or "E=...,nu=...,rho=...,zeta=..."
        (rig.muscle.material.parse_material); it sets the three values below that are None.
    frequency_hz : natural frequency of the goal springs, Hz, for a particle of goal weight 1/2 at
        strength 1; None: the material's at the part's real size (sim.jiggle.materials.with_material).
    damping_ratio : of the goal springs (1 = critical); None: the one that makes the part ring down with
        the material's ratio.
    goal_tendon, goal_belly : goal weights (0..1) at the tendon ends and in the belly.
    density : kg/m^3, for the particle masses; None: the material's.
    strength : jiggle strength in [0, 1]: the goal springs' compliance scale (0 glues the particles to
        their goals; an offset under a given acceleration grows in proportion to it).
    spring_frequency_hz : neighbour springs, as the frequency of one spring on the mean particle
        mass, Hz (0: no neighbour springs).
    spring_damping_ratio : of the neighbour springs.
    friction : drag on the particles' world velocity, 1/s.
    """

    frequency_hz: float | None
    damping_ratio: float | None
    goal_tendon: float
    goal_belly: float
    density: float | None
    strength: float = 1.0
    spring_frequency_hz: float = 7.0
    spring_damping_ratio: float = 0.3
    friction: float = 0.0
    material: str = "muscle"

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "material":
                object.__setattr__(self, f.name, str(v).strip())
            elif v is not None or f.name not in MATERIAL_SET:
                object.__setattr__(self, f.name, float(v))

    @property
    def from_material(self) -> tuple[str, ...]:
        """The fields the material sets (those left None)."""
        return tuple(k for k in MATERIAL_SET if getattr(self, k) is None)


MATERIAL_SET = ("frequency_hz", "damping_ratio", "density")
"""The Jiggle fields a part's material sets where the template leaves them out."""


# Where the defaults come from (sim/jiggle/tissue_law.py says what the reach and the stiffening are); the
# frequencies, damping and densities below are TUNED_SPRINGS, the templates' defaults before the materials set them:
# - Muscle frequency 10-12 Hz (11 by default; 10 for the big leg and hip muscles, 12 for the small forearm and
#   calf muscles, in the templates): measured free vibrations of relaxed human muscle lie at 7-18 Hz -- the
#   relaxed forearm (brachioradialis) 7-13 Hz (Gallasch & Kenner, "Characterisation of arm microvibration
#   recorded on an accelerometer", 1997), superficial muscles tapped at rest 12-18 Hz (MyotonPRO reference
#   ranges), the rectus femoris ~10 Hz in isometric extension (Humphries et al. 2004, J Sports Sci Med
#   3:16-22) -- and rise with muscle force and shortening (Wakeling & Nigg 2001, J Appl Physiol 90:412-420).
# - Muscle damping ratio 0.5: relaxed muscle rings with a log decrement of 1.0-1.6 (zeta 0.16-0.25, MyotonPRO
#   ranges); contraction raises the damping (Wakeling & Nigg 2001; Wakeling, Nigg & Rozitis 2002, J Appl
#   Physiol 93:1093-1103, where muscle activity damps the soft-tissue resonance), and a moving character's
#   muscles are active.
# - Fat 4 Hz, damping 0.3: slower and less damped than muscle, as loosely held tissue sways visibly longer
#   (a softer fat, 2.8 Hz at goal 0.15, swung 15 cm off a running body). No free-vibration measurement of
#   abdominal or gluteal fat was found; 4 Hz keeps the fat below the muscles' measured range and near the
#   2-14 Hz of voluntary movement, so it answers the motion itself.
# - Densities: skeletal muscle about 1060 kg/m^3, adipose tissue about 900. Neighbour springs carry a wobble
#   along the muscle as a wave (muscle 7 Hz, fat 4 Hz).
# - Reach (sim/jiggle/params.py MAX_OFFSET_RADII): 1.5 mean radii for a muscle, 2.5 for fat, times the
#   strength; the tissue law is linear to half of it, so walks, runs, jumps and dances stay in the linear
#   range in 99% of the frames on the shared clips (benchmarks/bench_tissue.py).
MUSCLE_JIGGLE = Jiggle(frequency_hz=None, damping_ratio=None, goal_tendon=0.9, goal_belly=0.4, density=None,
                       spring_frequency_hz=7.0, spring_damping_ratio=0.3, material="muscle")
FAT_JIGGLE = Jiggle(frequency_hz=None, damping_ratio=None, goal_tendon=0.9, goal_belly=0.3, density=None,
                    spring_frequency_hz=4.0, spring_damping_ratio=0.2, material="fat")
"""The kinds' defaults: their springs, damping and density from their material (rig.muscle.material) at the
part's real size. TUNED_SPRINGS are the values the templates had before (the comment above gives their sources),
which a rig built in code without templates (the thesis's simple arm, sim.jiggle.materials.default_jiggles) still
uses."""
TUNED_SPRINGS = {"muscle": {"frequency_hz": 11.0, "damping_ratio": 0.5, "density": 1060.0},
                 "fat": {"frequency_hz": 4.0, "damping_ratio": 0.3, "density": 900.0}}


def default_jiggle(kind: str) -> Jiggle:
    """The jiggle parameters a muscle of this kind gets when its template gives none."""
    return FAT_JIGGLE if kind == "fat" else MUSCLE_JIGGLE


FAT_DEPTH = 0.02
"""metres: the fat layer's thickness when a fat entry gives no depth (a moderate 2 cm)."""


def default_depth(kind: str) -> float:
    """The depth (metres) a muscle of this kind gets when its template gives none: FAT_DEPTH for fat,
    0 for muscles (their thinnest radius is thickness_min)."""
    return FAT_DEPTH if kind == "fat" else 0.0


@dataclass(frozen=True)
class MuscleTemplate:
    """One muscle (or fat mass) of a template; see the module docstring for the meaning of each field.

    span : (t0, t1) fraction along the bone; sector : (a0, a1) degrees about the bone or None.
    depth : metres. depth, jiggle and shell given as None at construction take the kind's default
    (:func:`default_depth`, :func:`default_jiggle`, :func:`rig.muscle.shell_params.default_shell`), so templates
    compare equal whether a default was written out or left to apply.
    """

    name: str
    pair_id: int | None = None
    type: str = "single"
    kind: str = "muscle"
    count: int = 1
    origin: Attachment = Attachment()
    o_hinge: Attachment = Attachment()
    i_hinge: Attachment = Attachment()
    insertion: Attachment = Attachment()
    span: tuple[float, float] = (0.0, 1.0)
    sector: tuple[float, float] | None = None
    rim_scale: float = 1.0
    bulge_scale: float = 1.0
    main_scale: float = 1.0
    bulge_position: float = 0.25
    tone: float = 1.0
    nu: float = 3.0
    thickness_min: float = 0.004
    depth: float | None = None  # None -> default_depth(kind)
    jiggle: Jiggle | None = None
    shell: ShellParams | None = None  # None -> default_shell(kind)

    def __post_init__(self):
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731 (frozen dataclass)
        set_("span", tuple(float(v) for v in self.span))
        if self.sector is not None:
            set_("sector", tuple(float(v) for v in self.sector))
        for k in ("rim_scale", "bulge_scale", "main_scale", "bulge_position", "tone", "nu", "thickness_min"):
            set_(k, float(getattr(self, k)))
        set_("depth", default_depth(self.kind) if self.depth is None else float(self.depth))
        if self.jiggle is None:
            set_("jiggle", default_jiggle(self.kind))
        if self.shell is None:
            set_("shell", default_shell(self.kind))

    def attachment(self, which: str) -> Attachment:
        """The attachment `which` ("origin", "o_hinge", "i_hinge" or "insertion")."""
        return getattr(self, which)


@dataclass(frozen=True)
class BoneMusclePair:
    """The muscles fitted to one bone's skin region.

    parent, child : role labels of the bone's start and end joints.
    partition_deg : angle of the partition plane's normal about the bone, degrees from e_front
        toward e_side (0: front/back split); used by "upper"/"lower" muscles.
    muscles : the muscles on this bone.
    reference : the world direction e_front is made from: "front" (the character's front) or "up"
        (+Z: the back of a horizontal spine, neck or tail, whose bone points along the front).
    """

    parent: str
    child: str
    partition_deg: float = 0.0
    muscles: tuple[MuscleTemplate, ...] = ()
    reference: str = "front"

    def __post_init__(self):
        object.__setattr__(self, "partition_deg", float(self.partition_deg))
        object.__setattr__(self, "muscles", tuple(self.muscles))

    def riding(self, muscle: MuscleTemplate) -> tuple[str, str, str, str]:
        """Role labels of the bones that `muscle`'s origin, origin hinge, insertion hinge and insertion
        ride, with the defaults applied (origin and hinges: parent, insertion: child)."""
        default = {"origin": self.parent, "o_hinge": self.parent, "i_hinge": self.parent, "insertion": self.child}
        return tuple(muscle.attachment(w).joint or default[w] for w in ATTACHMENTS)


@dataclass(frozen=True)
class Template:
    """A musculoskeletal template.

    name : a label ("human").
    pairs : the bones and their muscles, in file order.
    source : the file it was read from ("" when built in code); not part of equality, so the same
        template read from its XML and its TOML form compares equal.
    """

    name: str
    pairs: tuple[BoneMusclePair, ...]
    source: str = field(default="", compare=False)

    def __post_init__(self):
        object.__setattr__(self, "pairs", tuple(self.pairs))

    def muscles(self) -> tuple[tuple[BoneMusclePair, MuscleTemplate], ...]:
        """Every muscle with the pair it belongs to, in file order."""
        return tuple((p, m) for p in self.pairs for m in p.muscles)

    def labels(self) -> set[str]:
        """The role labels the template uses (bones and attachments)."""
        return {label for _, label in _label_uses(self)}


# ----------------------------------------------------------------------------------- validation
def _label_uses(t: Template):
    """(field, label) for every label the template names."""
    for i, p in enumerate(t.pairs):
        yield f"pair[{i}].bone", p.parent
        yield f"pair[{i}].bone", p.child
        for j, m in enumerate(p.muscles):
            for w in ATTACHMENTS:
                joint = m.attachment(w).joint
                if joint is not None:
                    yield f"pair[{i}].muscle[{j}].{w}.parent_joint", joint


def _fmt_range(lo, hi, lo_open=False, hi_open=False) -> str:
    g = lambda v: f"{v:g}"  # noqa: E731
    return f"{'(' if lo_open else '['}{g(lo)}, {g(hi)}{')' if hi_open else ']'}"


class _Checker:
    """Raises InputError naming the file, the field and (XML) the line of the element it came from."""

    def __init__(self, path: str | None, lines: dict[str, int] | None):
        self.path = path
        self.lines = {} if lines is None else lines

    def line(self, fld: str) -> int | None:
        while fld:
            if fld in self.lines:
                return self.lines[fld]
            cut = max(fld.rfind("."), fld.rfind("["))
            fld = fld[:cut] if cut > 0 else ""
        return None

    def fail(self, message: str, fld: str):
        raise InputError(message, self.path, line=self.line(fld), field=fld)

    def number(self, value, fld: str, lo, hi, lo_open=False, hi_open=False, unit: str = "") -> None:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        if ok:
            ok = (value > lo if lo_open else value >= lo) and (value < hi if hi_open else value <= hi)
        if not ok:
            self.fail(f"expected a number in {_fmt_range(lo, hi, lo_open, hi_open)}{unit}, got {value!r}", fld)

    def choice(self, value, fld: str, options) -> None:
        if value not in options:
            self.fail(f"expected one of {', '.join(options)}, got {value!r}", fld)

    def shell(self, values, fld: str) -> None:
        """Check deformer parameters (a ShellParams or {attr: value} with all six) with the ranges of
        rig.muscle.shell_params.check_params, naming `fld`.<parameter>."""
        get = values.get if isinstance(values, dict) else lambda k: getattr(values, k)
        try:
            check_params(*(get(attr) for attr, _ in _SHELL), where=fld)
        except InputError as e:
            self.fail(e.message, e.field or fld)

    def material(self, value, fld: str) -> None:
        """Fail unless `value` names a material (rig.muscle.material.parse_material)."""
        from jiggle.rig.muscle.material import parse_material
        try:
            parse_material(value, where="material")
        except InputError as e:
            self.fail(e.message, fld)

    def label(self, value, fld: str) -> None:
        if value not in LABELS:
            self.fail(f"unknown joint label {value!r}; template labels are roles: human {', '.join(ROLES)}; "
                      f"quadruped {', '.join(QUADRUPED_ROLES)}", fld)


def validate_template(t: Template, path: str | None = None, lines: dict[str, int] | None = None) -> Template:
    """Check every label, choice and number of `t` against its range; return `t`.

    Raises InputError naming `path` (default ``t.source``), the field (``pair[3].muscle[1].tone``)
    and, when `lines` maps fields to lines, the line.
    """
    c = _Checker(path if path is not None else (t.source or None), lines)
    if not isinstance(t.name, str) or not t.name.strip() or not t.name.isprintable():
        c.fail(f"expected a non-empty printable name, got {t.name!r}", "name")
    if not t.pairs:
        c.fail("the template has no bone muscle pairs", "pair")
    names: dict[str, str] = {}
    pair_ids: dict[int, int] = {}
    for i, p in enumerate(t.pairs):
        pf = f"pair[{i}]"
        c.label(p.parent, f"{pf}.bone")
        c.label(p.child, f"{pf}.bone")
        if p.parent == p.child:
            c.fail(f"a bone needs two different joints, got {p.parent!r} twice", f"{pf}.bone")
        c.number(p.partition_deg, f"{pf}.partition", -360, 360, unit=" degrees")
        c.choice(p.reference, f"{pf}.reference", REFERENCES)
        if not p.muscles:
            c.fail("the pair has no muscles", f"{pf}.muscle")
        halves: dict[tuple[int, str], int] = {}
        for j, m in enumerate(p.muscles):
            mf = f"{pf}.muscle[{j}]"
            if not isinstance(m.name, str) or not _NAME.match(m.name):
                c.fail(f"expected a name of letters, digits, '_', '.', '-' starting with a letter, got {m.name!r}",
                       f"{mf}.name")
            if m.name in names:
                c.fail(f"muscle name {m.name!r} is used twice (first at {names[m.name]})", f"{mf}.name")
            names[m.name] = mf
            c.choice(m.type, f"{mf}.type", TYPES)
            c.choice(m.kind, f"{mf}.kind", KINDS)
            if m.pair_id is not None:
                if isinstance(m.pair_id, bool) or not isinstance(m.pair_id, int) or m.pair_id < 0:
                    c.fail(f"expected a non-negative integer, got {m.pair_id!r}", f"{mf}.pair_id")
                if pair_ids.setdefault(m.pair_id, i) != i:
                    c.fail(f"pair id {m.pair_id} is already used by pair[{pair_ids[m.pair_id]}] (another bone)",
                           f"{mf}.pair_id")
            if m.type != "single":
                if m.pair_id is None:
                    c.fail(f"an {m.type!r} muscle is half of a pair and needs a pair id", f"{mf}.pair_id")
                if (m.pair_id, m.type) in halves:
                    c.fail(f"pair id {m.pair_id} already has an {m.type!r} muscle "
                           f"({p.muscles[halves[m.pair_id, m.type]].name})", f"{mf}.type")
                halves[m.pair_id, m.type] = j
            if isinstance(m.count, bool) or not isinstance(m.count, int) or not 1 <= m.count <= MAX_BELLIES:
                c.fail(f"expected an integer in [1, {MAX_BELLIES}], got {m.count!r}", f"{mf}.count")
            if m.kind != "multi_belly" and m.count != 1:
                c.fail(f"count is the number of bellies of a 'multi_belly' muscle; a {m.kind!r} has 1, got "
                       f"{m.count}", f"{mf}.count")
            for w in ATTACHMENTS:
                a = m.attachment(w)
                if a.joint is not None:
                    c.label(a.joint, f"{mf}.{w}.parent_joint")
                if a.position is not None:
                    pos = a.position
                    c.choice(pos.type, f"{mf}.{w}.position.type", POSITION_TYPES)
                    bound, unit = (10.0, " bone lengths") if pos.type == "relative" else (1000.0, " metres")
                    for axis, v in zip("xyz", pos.xyz):
                        c.number(v, f"{mf}.{w}.position.{axis}", -bound, bound, unit=unit)
            t0, t1 = m.span
            c.number(t0, f"{mf}.span", -0.5, 1.5, unit=" (t0, fraction of the bone)")
            c.number(t1, f"{mf}.span", -0.5, 1.5, unit=" (t1, fraction of the bone)")
            if not t0 < t1:
                c.fail(f"expected t0 < t1, got ({t0:g}, {t1:g})", f"{mf}.span")
            if m.sector is not None:
                a0, a1 = m.sector
                c.number(a0, f"{mf}.sector", -360, 360, unit=" (a0, degrees)")
                c.number(a1, f"{mf}.sector", -360, 720, unit=" (a1, degrees)")
                if not a0 < a1 <= a0 + 360:
                    c.fail(f"expected a0 < a1 <= a0 + 360 degrees, got ({a0:g}, {a1:g})", f"{mf}.sector")
            for k in ("rim_scale", "bulge_scale", "main_scale"):
                c.number(getattr(m, k), f"{mf}.{k}", 0, 10, lo_open=True)
            c.number(m.bulge_position, f"{mf}.bulge_position", 0, 0.5)
            c.number(m.tone, f"{mf}.tone", 0, 1)
            c.number(m.nu, f"{mf}.nu", 0, 100)
            c.number(m.thickness_min, f"{mf}.thickness_min", 0, 0.5, unit=" metres")
            c.number(m.depth, f"{mf}.depth", 0, 0.5, unit=" metres")
            jg = m.jiggle
            c.material(jg.material, f"{mf}.jiggle.material")
            if jg.frequency_hz is not None:
                c.number(jg.frequency_hz, f"{mf}.jiggle.frequency", 0, 100, lo_open=True, unit=" Hz")
            if jg.damping_ratio is not None:
                c.number(jg.damping_ratio, f"{mf}.jiggle.damping", 0, 10)
            c.number(jg.goal_tendon, f"{mf}.jiggle.goal_tendon", 0, 1)
            c.number(jg.goal_belly, f"{mf}.jiggle.goal_belly", 0, 1)
            if jg.density is not None:
                c.number(jg.density, f"{mf}.jiggle.density", 100, 5000, unit=" kg/m^3")
            c.number(jg.strength, f"{mf}.jiggle.strength", 0, 1)
            c.number(jg.spring_frequency_hz, f"{mf}.jiggle.spring_frequency", 0, 100, unit=" Hz")
            c.number(jg.spring_damping_ratio, f"{mf}.jiggle.spring_damping", 0, 10)
            c.number(jg.friction, f"{mf}.jiggle.friction", 0, 100, unit=" 1/s")
            if not isinstance(m.shell, ShellParams):
                c.fail(f"expected rig.muscle.shell_params.ShellParams, got {type(m.shell).__name__}", f"{mf}.shell")
            c.shell(m.shell, f"{mf}.shell")
    return t


def check_labels(template: Template, roles: dict[str, int], joint_names=None, plan=None) -> None:
    """Raise InputError when `template` uses a label the skeleton's role map `roles` ({role: joint
    index}, from ``rig.motion.role_map.resolve_roles``) lacks. The message lists the missing labels with the
    first field naming each, and the known labels (the roles found, with their joints when
    `joint_names` is given); with the skeleton's `plan` (rig.motion.body_plan.BodyPlan) it names the
    template that fits it when this one is for another body plan."""
    missing: dict[str, str] = {}
    for fld, label in _label_uses(template):
        if label not in roles:
            missing.setdefault(label, fld)
    if not missing:
        return
    known = []
    for role in sorted(roles, key=lambda r: LABELS.index(r) if r in LABELS else len(LABELS)):
        j = roles[role]
        if joint_names is not None and 0 <= j < len(joint_names):
            known.append(f"{role} ({joint_names[j]})")
        else:
            known.append(role)
    what = ", ".join(f"{label!r} (at {fld})" for label, fld in missing.items())
    first = next(iter(missing.values()))
    hint = "give a joint map that names the missing roles"
    if plan is not None and plan.template is not None and plan.template != template.name:
        hint = (f"the skeleton is a {plan.kind} ({plan.reason}): its template is {plan.template!r}, which "
                f"--template auto (the default) picks; or " + hint)
    raise InputError(f"the skeleton's role map has no joint for template label(s) {what}; known labels: "
                     f"{', '.join(known) or 'none'} ({hint})", template.source or None, field=first)


# ----------------------------------------------------------------------------------- shared reading
# TOML key (snake_case) <-> XML attribute (camelCase), per element
_SECTIONS = (("rim_scale", "rim"), ("bulge_scale", "bulge"), ("main_scale", "main"),
             ("bulge_position", "bulgePosition"))
_SHAPE = (("tone", "tone"), ("nu", "nu"), ("thickness_min", "thicknessMin"), ("depth", "depth"),
          ("count", "count"))
_JIGGLE = (("material", "material", "material"), ("frequency", "frequency", "frequency_hz"), ("damping", "damping", "damping_ratio"),
           ("goal_tendon", "goalTendon", "goal_tendon"), ("goal_belly", "goalBelly", "goal_belly"),
           ("density", "density", "density"), ("strength", "strength", "strength"),
           ("spring_frequency", "springFrequency", "spring_frequency_hz"),
           ("spring_damping", "springDamping", "spring_damping_ratio"), ("friction", "friction", "friction"))
_SHELL = (("sticky", "sticky"), ("hard", "hard"), ("drop_off", "dropOff"), ("weight", "weight"),
          ("slippage", "slippage"), ("mode", "mode"))  # ShellParams attribute = TOML key
_XML_ATTACH = {"origin": "origin", "o_hinge": "oHinge", "i_hinge": "iHinge", "insertion": "insertion"}


def _jiggle_of(kind, given: dict) -> Jiggle:
    """A Jiggle from {snake key: value}, the kind's default filling what is missing."""
    base = default_jiggle(kind if kind in KINDS else "muscle")
    return Jiggle(**{attr: given.get(key, getattr(base, attr)) for key, _, attr in _JIGGLE})


def _shell_of(kind, given: dict, c: _Checker, fld: str) -> ShellParams:
    """A ShellParams from {snake key: value} (numbers and a mode string, types already checked), the
    kind's default filling what is missing; ranges are checked here so that the error names `fld`
    (``pair[0].muscle[1].shell.sticky``), the file and the line, not just the parameter."""
    base = default_shell(kind if kind in KINDS else "muscle")
    values = {attr: given.get(attr, getattr(base, attr)) for attr, _ in _SHELL}
    c.shell(values, fld)
    return ShellParams(**values)


def _stem(path: str | None) -> str:
    return os.path.splitext(os.path.basename(path))[0] if path else "template"


def _muscle_of(kw: dict, jiggle: dict, shell: dict | None, c: _Checker, fld: str) -> MuscleTemplate:
    """The MuscleTemplate of the fields read (`kw`, {MuscleTemplate field: value}) and the jiggle and
    shell values given ({TOML key: value}; `shell` None when the file gives no shell), the kind's
    defaults filling what is missing; `fld` is the muscle's field (``pair[0].muscle[1]``)."""
    kind = kw.get("kind", "muscle")
    kw["jiggle"] = _jiggle_of(kind, jiggle)
    if shell is not None:
        kw["shell"] = _shell_of(kind, shell, c, f"{fld}.shell")
    return MuscleTemplate(**kw)


# ----------------------------------------------------------------------------------- TOML
_TOML_MUSCLE_KEYS = ("name", "pair_id", "type", "kind", "count", *ATTACHMENTS, "span", "sector", "rim_scale",
                     "bulge_scale", "main_scale", "bulge_position", "tone", "nu", "thickness_min", "depth", "jiggle",
                     "shell")
_TOML_NUMBERS = ("rim_scale", "bulge_scale", "main_scale", "bulge_position", "tone", "nu", "thickness_min", "depth")


class _TomlReader:
    """Reads the tables of a parsed TOML template; every problem fails through the _Checker, naming the
    file and the field."""

    def __init__(self, path: str | None):
        self.path = path
        self.c = _Checker(path, None)

    def keys(self, table, fld, allowed, required=()):
        """Fail unless `table` is a table whose keys are among `allowed` and include `required`."""
        if not isinstance(table, dict):
            self.c.fail(f"expected a table, got {table!r}", fld)
        extra = [k for k in table if k not in allowed]
        if extra:
            self.c.fail(f"unknown key(s) {', '.join(map(repr, extra))}; expected {', '.join(allowed)}",
                        f"{fld}.{extra[0]}" if fld else extra[0])
        for k in required:
            if k not in table:
                self.c.fail(f"missing key {k!r}", f"{fld}.{k}" if fld else k)

    def num(self, v, fld):
        """`v` as a float; fail unless it is a TOML number."""
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.c.fail(f"expected a number, got {v!r}", fld)
        return float(v)

    def integer(self, v, fld):
        """`v`; fail unless it is a TOML integer."""
        if isinstance(v, bool) or not isinstance(v, int):
            self.c.fail(f"expected an integer, got {v!r}", fld)
        return v

    def string(self, v, fld):
        """`v`; fail unless it is a TOML string."""
        if not isinstance(v, str):
            self.c.fail(f"expected a string, got {v!r}", fld)
        return v

    def pair_of(self, v, fld, conv):
        """(2,) tuple of `v`, a list of two values, each converted by `conv(value, fld)`."""
        if not isinstance(v, list) or len(v) != 2:
            self.c.fail(f"expected a list of two values, got {v!r}", fld)
        return tuple(conv(x, fld) for x in v)

    def template(self, doc: dict) -> tuple[str, tuple[BoneMusclePair, ...]]:
        """The name and the pairs of the document `doc`."""
        self.keys(doc, "", ("name", "pair"), required=("pair",))
        name = self.string(doc["name"], "name") if "name" in doc else _stem(self.path)
        if not isinstance(doc["pair"], list):
            self.c.fail("expected an array of tables [[pair]]", "pair")
        return name, tuple(self.pair(pt, f"pair[{i}]") for i, pt in enumerate(doc["pair"]))

    def pair(self, pt, pf) -> BoneMusclePair:
        """One [[pair]] table; `pf` its field (``pair[3]``)."""
        self.keys(pt, pf, ("bone", "partition", "reference", "muscle"), required=("bone", "muscle"))
        parent, child = self.pair_of(pt["bone"], f"{pf}.bone", self.string)
        partition = self.num(pt["partition"], f"{pf}.partition") if "partition" in pt else 0.0
        reference = self.string(pt["reference"], f"{pf}.reference") if "reference" in pt else "front"
        if not isinstance(pt["muscle"], list):
            self.c.fail("expected an array of tables [[pair.muscle]]", f"{pf}.muscle")
        muscles = tuple(self.muscle(mt, f"{pf}.muscle[{j}]") for j, mt in enumerate(pt["muscle"]))
        return BoneMusclePair(parent, child, partition, muscles, reference)

    def attachment(self, v, fld) -> Attachment:
        """An inline table { parent_joint, position } of a muscle's attachment point."""
        self.keys(v, fld, ("parent_joint", "position"))
        pos = None
        if "position" in v:
            pv, pf = v["position"], f"{fld}.position"
            self.keys(pv, pf, ("type", "x", "y", "z"), required=("type", "x", "y", "z"))
            pos = Position(self.string(pv["type"], f"{pf}.type"), tuple(self.num(pv[a], f"{pf}.{a}") for a in "xyz"))
        joint = self.string(v["parent_joint"], f"{fld}.parent_joint") if "parent_joint" in v else None
        return Attachment(joint, pos)

    def muscle(self, mt, mf) -> MuscleTemplate:
        """One [[pair.muscle]] table; `mf` its field (``pair[3].muscle[1]``)."""
        self.keys(mt, mf, _TOML_MUSCLE_KEYS, required=("name",))
        kw = {"name": self.string(mt["name"], f"{mf}.name")}
        if "pair_id" in mt:
            kw["pair_id"] = self.integer(mt["pair_id"], f"{mf}.pair_id")
        for k in ("type", "kind"):
            if k in mt:
                kw[k] = self.string(mt[k], f"{mf}.{k}")
        if "count" in mt:
            kw["count"] = self.integer(mt["count"], f"{mf}.count")
        for w in ATTACHMENTS:
            if w in mt:
                kw[w] = self.attachment(mt[w], f"{mf}.{w}")
        for k in ("span", "sector"):
            if k in mt:
                kw[k] = self.pair_of(mt[k], f"{mf}.{k}", self.num)
        for k in _TOML_NUMBERS:
            if k in mt:
                kw[k] = self.num(mt[k], f"{mf}.{k}")
        jiggle, shell = {}, None
        if "jiggle" in mt:
            jf = f"{mf}.jiggle"
            self.keys(mt["jiggle"], jf, tuple(k for k, _, _ in _JIGGLE))
            jiggle = {k: self.string(v, f"{jf}.{k}") if k == "material" else self.num(v, f"{jf}.{k}")
                      for k, v in mt["jiggle"].items()}
        if "shell" in mt:
            sf = f"{mf}.shell"
            self.keys(mt["shell"], sf, tuple(k for k, _ in _SHELL))
            shell = {k: self.string(v, f"{sf}.{k}") if k == "mode" else self.num(v, f"{sf}.{k}")
                     for k, v in mt["shell"].items()}
        return _muscle_of(kw, jiggle, shell, self.c, mf)


def template_from_toml(text: str, path: str | None = None) -> Template:
    """Parse the TOML form; InputError naming `path` and the field for any problem."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(f"not valid TOML: {e}", path) from None
    name, pairs = _TomlReader(path).template(doc)
    return validate_template(Template(name, pairs, source=path or ""), path)


def _toml_str(s: str) -> str:
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _num_str(v) -> str:
    return str(v) if isinstance(v, int) and not isinstance(v, bool) else repr(float(v))


def template_to_toml(t: Template) -> str:
    """The TOML form of `t` (every set value written; read back it compares equal)."""
    validate_template(t)
    lines = ["# jiggle musculoskeletal template (rig/muscle/template.py describes the fields)",
             f"name = {_toml_str(t.name)}", ""]
    for p in t.pairs:
        lines += ["[[pair]]", f"bone = [{_toml_str(p.parent)}, {_toml_str(p.child)}]",
                  f"partition = {_num_str(p.partition_deg)}"]
        lines += [f"reference = {_toml_str(p.reference)}", ""] if p.reference != "front" else [""]
        for m in p.muscles:
            lines += ["[[pair.muscle]]", f"name = {_toml_str(m.name)}"]
            if m.pair_id is not None:
                lines.append(f"pair_id = {m.pair_id}")
            lines += [f"type = {_toml_str(m.type)}", f"kind = {_toml_str(m.kind)}", f"count = {m.count}"]
            for w in ATTACHMENTS:
                a = m.attachment(w)
                parts = []
                if a.joint is not None:
                    parts.append(f"parent_joint = {_toml_str(a.joint)}")
                if a.position is not None:
                    x, y, z = a.position.xyz
                    parts.append(f"position = {{ type = {_toml_str(a.position.type)}, x = {_num_str(x)}, "
                                 f"y = {_num_str(y)}, z = {_num_str(z)} }}")
                if parts:
                    lines.append(f"{w} = {{ {', '.join(parts)} }}")
            lines.append(f"span = [{_num_str(m.span[0])}, {_num_str(m.span[1])}]")
            if m.sector is not None:
                lines.append(f"sector = [{_num_str(m.sector[0])}, {_num_str(m.sector[1])}]")
            for k in ("rim_scale", "bulge_scale", "main_scale", "bulge_position", "tone", "nu", "thickness_min"):
                lines.append(f"{k} = {_num_str(getattr(m, k))}")
            lines.append(f"depth = {_num_str(m.depth)}")
            jg = ", ".join(f"{k} = {_toml_str(m.jiggle.material) if k == 'material' else _num_str(getattr(m.jiggle, attr))}"
                           for k, _, attr in _JIGGLE if getattr(m.jiggle, attr) is not None)
            lines.append(f"jiggle = {{ {jg} }}")
            sh = ", ".join(f"{k} = {_toml_str(m.shell.mode) if k == 'mode' else _num_str(getattr(m.shell, k))}"
                           for k, _ in _SHELL)
            lines += [f"shell = {{ {sh} }}", ""]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------- XML
class _LineTreeBuilder(ET.TreeBuilder):
    """A TreeBuilder that remembers the line each element starts on (expat knows it while parsing)."""

    def __init__(self):
        super().__init__()
        self.expat = None
        self.lines: dict[int, int] = {}

    def start(self, tag, attrs):
        elem = super().start(tag, attrs)
        if self.expat is not None:
            self.lines[id(elem)] = self.expat.CurrentLineNumber
        return elem


def _parse_xml(data: bytes, path: str | None) -> tuple[ET.Element, dict[int, int]]:
    """The root element and {id(element): line}; InputError for malformed or hostile XML."""
    builder = _LineTreeBuilder()
    parser = DefusedXMLParser(target=builder, forbid_dtd=True, forbid_entities=True, forbid_external=True)
    builder.expat = parser.parser
    try:
        parser.feed(data)
        root = parser.close()
    except ET.ParseError as e:
        line = e.position[0] if getattr(e, "position", None) else None
        msg = re.sub(r":\s*line \d+, column \d+$", "", str(e))
        raise InputError(f"not well-formed XML: {msg}", path, line=line) from None
    except LookupError as e:     # <?xml ... encoding="..."?> naming an encoding Python does not know
        raise InputError(f"the XML declaration names an unknown encoding ({e}); expected UTF-8", path, line=1,
                         field="encoding") from None
    except DefusedXmlException as e:
        line = getattr(parser.parser, "CurrentLineNumber", None)
        if isinstance(e, DTDForbidden):
            what = "a document type declaration (<!DOCTYPE ...>)"
        elif isinstance(e, EntitiesForbidden):
            what = f"an entity declaration ({e.name!r})"
        elif isinstance(e, ExternalReferenceForbidden):
            what = "a reference to an external resource"
        else:
            what = "an unsafe construct"
        raise InputError(f"refused: the XML holds {what}; templates use no DTDs or entities (they could expand "
                         f"without bound or read other files)", path, line=line) from None
    return root, builder.lines


_XML_MUSCLE_CHILDREN = ("name", *_XML_ATTACH.values(), "span", "sector", "sections", "shape", "jiggle", "shell")


class _XmlReader:
    """Reads the elements of a parsed XML template. Every field read is recorded in `lines` ({field:
    line}, kept for validate_template's errors too) with the line of its element; every problem fails
    through the _Checker, naming the file, the field (in the TOML spelling) and the line.

    elem_lines : {id(element): line}, from _parse_xml.
    """

    def __init__(self, path: str | None, elem_lines: dict[int, int]):
        self.path = path
        self.elem_lines = elem_lines
        self.lines: dict[str, int] = {}
        self.c = _Checker(path, self.lines)

    def at(self, elem, fld):
        """`fld`, its line recorded as `elem`'s unless one is recorded already."""
        if id(elem) in self.elem_lines:
            self.lines.setdefault(fld, self.elem_lines[id(elem)])
        return fld

    def no_text(self, elem, fld):
        """Fail when `elem` holds text besides its child elements."""
        for text in (elem.text, *(ch.tail for ch in elem)):
            if text and text.strip():
                self.c.fail(f"unexpected text {text.strip()!r} in <{elem.tag}>", fld)

    def children(self, elem, fld, allowed, repeat=()):
        """{tag: [elements]} of elem's children; unknown tags and repeats of single ones are errors."""
        self.no_text(elem, fld)
        out: dict[str, list] = {}
        for ch in elem:
            if ch.tag not in allowed:
                self.at(ch, f"{fld}.{ch.tag}")
                self.c.fail(f"unknown element <{ch.tag}> in <{elem.tag}>; expected "
                            f"{', '.join('<' + a + '>' for a in allowed)}", f"{fld}.{ch.tag}")
            if ch.tag in out and ch.tag not in repeat:
                self.at(ch, f"{fld}.{ch.tag}")
                self.c.fail(f"<{ch.tag}> given twice in <{elem.tag}>", f"{fld}.{ch.tag}")
            out.setdefault(ch.tag, []).append(ch)
        return out

    def attrs(self, elem, fld, allowed, required=()):
        """The attributes of `elem`; fail unless they are among `allowed` and include `required`."""
        extra = [a for a in elem.attrib if a not in allowed]
        if extra:
            self.c.fail(f"unknown attribute(s) {', '.join(extra)} of <{elem.tag}>; expected "
                        f"{', '.join(allowed) or 'none'}", fld)
        for a in required:
            if a not in elem.attrib:
                self.c.fail(f"<{elem.tag}> needs the attribute {a}", fld)
        return elem.attrib

    def leaf(self, elem, fld, allowed, required=()):
        """The attributes of `elem`, an element of attributes only (no text, no children), at field `fld`."""
        self.at(elem, fld)
        given = self.attrs(elem, fld, allowed, required)
        self.children(elem, fld, ())
        return given

    def text_of(self, elem, fld):
        """The stripped, non-empty text of `elem`, an element of text only."""
        if len(elem):
            self.c.fail(f"<{elem.tag}> holds text only, found <{elem[0].tag}>", fld)
        text = (elem.text or "").strip()
        if not text:
            self.c.fail(f"<{elem.tag}> is empty", fld)
        return text

    def num(self, s, fld):
        """The attribute text `s` as a float."""
        try:
            return float(s)
        except ValueError:
            self.c.fail(f"expected a number, got {s!r}", fld)

    def integer(self, s, fld):
        """The attribute text `s` as an int."""
        try:
            return int(s.strip())
        except ValueError:
            self.c.fail(f"expected an integer, got {s!r}", fld)

    def template(self, root) -> tuple[str, tuple[BoneMusclePair, ...]]:
        """The name and the pairs of the document whose root element is `root`."""
        if root.tag == "boneMusclePair":
            return _stem(self.path), (self.pair(root, 0),)
        if root.tag == "musculoskeletalTemplate":
            self.at(root, "name")
            name = self.attrs(root, "name", ("name",)).get("name", _stem(self.path))
            kids = self.children(root, "pair", ("boneMusclePair",), repeat=("boneMusclePair",))
            return name, tuple(self.pair(e, i) for i, e in enumerate(kids.get("boneMusclePair", [])))
        self.lines["template"] = self.elem_lines.get(id(root), 1)
        self.c.fail(f"the root element is <{root.tag}>; expected <musculoskeletalTemplate> or <boneMusclePair>",
                    "template")

    def pair(self, elem, i) -> BoneMusclePair:
        """One <boneMusclePair>, the template's pair `i`."""
        pf = self.at(elem, f"pair[{i}]")
        self.attrs(elem, pf, ())
        kids = self.children(elem, pf, ("bone", "partition", "muscle"), repeat=("muscle",))
        if "bone" not in kids:
            self.c.fail("<boneMusclePair> needs a <bone>", f"{pf}.bone")
        parent, child = self.bone(kids["bone"][0], f"{pf}.bone")
        partition, reference = 0.0, "front"
        if "partition" in kids:
            e = kids["partition"][0]
            f = self.at(e, f"{pf}.partition")
            given = self.attrs(e, f, ("angle", "reference"), required=("angle",))
            partition = self.num(given["angle"], f)
            reference = given.get("reference", "front")
            self.children(e, f, ())
        if "muscle" not in kids:
            self.c.fail("<boneMusclePair> has no <muscle>", f"{pf}.muscle")
        muscles = tuple(self.muscle(e, f"{pf}.muscle[{j}]") for j, e in enumerate(kids["muscle"]))
        return BoneMusclePair(parent, child, partition, muscles, reference)

    def bone(self, elem, fld) -> tuple[str, str]:
        """(parent, child) role labels of a <bone> element."""
        self.at(elem, fld)
        kids = self.children(elem, fld, ("parentJoint", "childJoint"))
        for tag in ("parentJoint", "childJoint"):
            if tag not in kids:
                self.c.fail(f"<bone> needs a <{tag}>", fld)
        return tuple(self.text_of(kids[t][0], fld) for t in ("parentJoint", "childJoint"))

    def attachment(self, elem, fld) -> Attachment:
        """An attachment element (<origin>, <oHinge>, <iHinge>, <insertion>): <parentJoint>, <position>."""
        self.at(elem, fld)
        self.attrs(elem, fld, ())
        kids = self.children(elem, fld, ("parentJoint", "position"))
        joint = pos = None
        if "parentJoint" in kids:
            joint = self.text_of(kids["parentJoint"][0], self.at(kids["parentJoint"][0], f"{fld}.parent_joint"))
        if "position" in kids:
            pe = kids["position"][0]
            pf = self.at(pe, f"{fld}.position")
            for a in ("type", "x", "y", "z"):
                self.at(pe, f"{pf}.{a}")
            given = self.leaf(pe, pf, ("type", "x", "y", "z"), required=("type", "x", "y", "z"))
            pos = Position(given["type"], tuple(self.num(given[k], f"{pf}.{k}") for k in "xyz"))
        return Attachment(joint, pos)

    def muscle(self, elem, mf) -> MuscleTemplate:
        """One <muscle>; `mf` its field (``pair[3].muscle[1]``)."""
        self.at(elem, mf)
        kw = self.muscle_attrs(elem, mf)
        kids = self.children(elem, mf, _XML_MUSCLE_CHILDREN)
        if "name" not in kids:
            self.c.fail("<muscle> needs a <name>", f"{mf}.name")
        kw["name"] = self.text_of(kids["name"][0], self.at(kids["name"][0], f"{mf}.name"))
        for w, tag in _XML_ATTACH.items():
            if tag in kids:
                kw[w] = self.attachment(kids[tag][0], f"{mf}.{w}")
        for k, ends in (("span", ("t0", "t1")), ("sector", ("a0", "a1"))):
            if k in kids:
                f = f"{mf}.{k}"
                given = self.leaf(kids[k][0], f, ends, required=ends)
                kw[k] = tuple(self.num(given[x], f) for x in ends)
        for tag, table in (("sections", _SECTIONS), ("shape", _SHAPE)):
            if tag in kids:
                e = kids[tag][0]
                given = self.leaf(e, f"{mf}.{tag}", tuple(x for _, x in table))
                for key, x in table:
                    if x in given:
                        f = self.at(e, f"{mf}.{key}")
                        kw[key] = self.integer(given[x], f) if key == "count" else self.num(given[x], f)
        return _muscle_of(kw, self.jiggle(kids, mf), self.shell(kids, mf), self.c, mf)

    def muscle_attrs(self, elem, mf) -> dict:
        """{MuscleTemplate field: value} of the <muscle> element's attributes (pairId, type, kind)."""
        a = self.attrs(elem, mf, ("pairId", "type", "kind"))
        kw = {}
        if "pairId" in a:
            kw["pair_id"] = self.integer(a["pairId"], self.at(elem, f"{mf}.pair_id"))
        for k in ("type", "kind"):
            if k in a:
                kw[k] = a[k].strip()
                self.at(elem, f"{mf}.{k}")
        return kw

    def jiggle(self, kids, mf) -> dict:
        """{TOML key: value} of the muscle's <jiggle> element ({} when it has none)."""
        if "jiggle" not in kids:
            return {}
        e = kids["jiggle"][0]
        jf = f"{mf}.jiggle"
        given = self.leaf(e, jf, tuple(x for _, x, _ in _JIGGLE))
        return {key: given[x].strip() if key == "material" else self.num(given[x], self.at(e, f"{jf}.{key}"))
                for key, x, _ in _JIGGLE if x in given}

    def shell(self, kids, mf) -> dict | None:
        """{TOML key: value} of the muscle's <shell> element (None when it has none)."""
        if "shell" not in kids:
            return None
        e = kids["shell"][0]
        sf = f"{mf}.shell"
        ea = self.leaf(e, sf, tuple(x for _, x in _SHELL))
        given = {key: ea[x].strip() if key == "mode" else self.num(ea[x], self.at(e, f"{sf}.{key}"))
                 for key, x in _SHELL if x in ea}
        if "mode" in given:
            self.at(e, f"{sf}.mode")
        return given


def template_from_xml(data: bytes | str, path: str | None = None) -> Template:
    """Parse the XML form (root ``musculoskeletalTemplate``, or a single ``boneMusclePair``);
    InputError naming `path`, the line and the field for any problem."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    root, elem_lines = _parse_xml(data, path)
    reader = _XmlReader(path, elem_lines)
    name, pairs = reader.template(root)
    return validate_template(Template(name, pairs, source=path or ""), path, reader.lines)


def template_to_xml(t: Template) -> str:
    """The XML form of `t` in the paper's layout (every set value written; read back it compares equal)."""
    validate_template(t)
    sub = ET.SubElement
    root = ET.Element("musculoskeletalTemplate", name=t.name)
    for p in t.pairs:
        pe = sub(root, "boneMusclePair")
        be = sub(pe, "bone")
        sub(be, "parentJoint").text = p.parent
        sub(be, "childJoint").text = p.child
        sub(pe, "partition", angle=_num_str(p.partition_deg),
            **({"reference": p.reference} if p.reference != "front" else {}))
        for m in p.muscles:
            attrib = {} if m.pair_id is None else {"pairId": str(m.pair_id)}
            me = sub(pe, "muscle", attrib, type=m.type, kind=m.kind)
            sub(me, "name").text = m.name
            for w, tag in _XML_ATTACH.items():
                a = m.attachment(w)
                if a.joint is None and a.position is None:
                    continue
                ae = sub(me, tag)
                if a.joint is not None:
                    sub(ae, "parentJoint").text = a.joint
                if a.position is not None:
                    x, y, z = (_num_str(v) for v in a.position.xyz)
                    sub(ae, "position", type=a.position.type, x=x, y=y, z=z)
            sub(me, "span", t0=_num_str(m.span[0]), t1=_num_str(m.span[1]))
            if m.sector is not None:
                sub(me, "sector", a0=_num_str(m.sector[0]), a1=_num_str(m.sector[1]))
            sub(me, "sections", {x: _num_str(getattr(m, k)) for k, x in _SECTIONS})
            sub(me, "shape", {x: _num_str(getattr(m, k)) for k, x in _SHAPE})
            sub(me, "jiggle", {x: m.jiggle.material if attr == "material" else _num_str(getattr(m.jiggle, attr))
                               for _, x, attr in _JIGGLE if getattr(m.jiggle, attr) is not None})
            sub(me, "shell", {x: m.shell.mode if k == "mode" else _num_str(getattr(m.shell, k)) for k, x in _SHELL})
    ET.indent(root, "  ")
    return ('<?xml version="1.0" encoding="utf-8"?>\n'
            "<!-- jiggle musculoskeletal template (rig/muscle/template.py describes the fields) -->\n"
            + ET.tostring(root, encoding="unicode") + "\n")


# ----------------------------------------------------------------------------------- files
def _suffix(path: str) -> str:
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in SUFFIXES:
        raise InputError(f"a template file ends in .xml or .toml, got {suffix or 'no suffix'!r}", path)
    return suffix


def _from_bytes(data: bytes, path: str) -> Template:
    if _suffix(path) == ".xml":
        return template_from_xml(data, path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError("not a UTF-8 text file; expected TOML", path) from None
    return template_from_toml(text, path)


def read_template(path: str | os.PathLike) -> Template:
    """Read a template file (.xml or .toml, by suffix)."""
    p = os.fspath(path)
    _suffix(p)
    p = require_file(p, "template file")
    with open(p, "rb") as fh:
        return _from_bytes(fh.read(), p)


def write_template(template: Template, path: str | os.PathLike) -> str:
    """Write `template` to `path` (.xml or .toml, by suffix) atomically (a temporary file in the same
    folder, then os.replace); return the path."""
    p = os.fspath(path)
    text = template_to_xml(template) if _suffix(p) == ".xml" else template_to_toml(template)
    with atomic_path(p) as tmp, open(tmp, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(text)
    return p


def builtin_templates() -> list[str]:
    """Names of the templates shipped in rig/muscle/templates (each in .toml and .xml form)."""
    folder = importlib.resources.files("jiggle.rig.muscle") / "templates"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def load_template(name_or_path: str | os.PathLike, form: str = ".toml") -> Template:
    """A template from a file path, or a built-in one by name ("human"; `form` ".toml" or ".xml" picks
    which of its two equal files is read)."""
    s = os.fspath(name_or_path)
    if os.path.isfile(s) or os.path.splitext(s)[1] or os.sep in s or "/" in s:
        return read_template(s)
    res = importlib.resources.files("jiggle.rig.muscle") / "templates" / f"{s}{form}"
    if form not in SUFFIXES or not res.is_file():
        raise InputError(f"no built-in template named {s!r} (form {form!r}); built-in templates are "
                         f"{', '.join(builtin_templates())}, or give a path to a .xml or .toml file",
                         field="template")
    return _from_bytes(res.read_bytes(), str(res))


__all__ = ["Position", "Attachment", "Jiggle", "MuscleTemplate", "BoneMusclePair", "Template", "MUSCLE_JIGGLE",
           "FAT_JIGGLE", "FAT_DEPTH", "default_jiggle", "default_depth", "validate_template", "check_labels", "template_from_toml",
           "template_to_toml", "template_from_xml", "template_to_xml", "read_template", "write_template",
           "load_template", "builtin_templates", "TYPES", "KINDS", "POSITION_TYPES", "ATTACHMENTS"]
