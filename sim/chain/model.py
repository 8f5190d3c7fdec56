"""A character's chains as one MuJoCo model: capsules on ball joints, hung from the animated body.

Why MuJoCo: a chain of bones is a chain of rigid bodies, and MuJoCo simulates those exactly in reduced
coordinates (bones keep their lengths by construction, no constraint drift), with soft contacts against capsules
and planes, gravity, joint springs and damping (the semi-implicit Euler step takes joint damping implicitly) and
soft joint limits, all in C; a character's chains are tens of bodies, the size MuJoCo is fastest at on one CPU
core. Air drag is applied per link by sim.chain.simulate (MuJoCo's ellipsoid fluid model doubles a step's cost).

    world
      floor plane (the bake's floor, when it has one)
      per joint a chain hangs from (an anchor): a heavy body on three slide joints and a ball joint (a free joint
        whose translation and rotation have springs of their own), carrying the joint's capsules
        (rig.character.capsules). sim.chain.simulate drives it along the animation with the force its motion
        needs (mass times the animation's acceleration, gravity compensated) while its joints' springs and
        damping (critical, ANCHOR_TIMECONST) pull it onto the animated pose against any drift: so the chain
        hanging from it feels the body's accelerations (a chain hung from a mocap body would be teleported with
        it and never swing), and no constraint is solved for it (a weld to a mocap target cost half the step)
      per other joint whose capsules a chain can reach: a mocap body carrying them, posed each step
        chain links: one body per chain joint at its bind transform, a ball joint at its origin, a capsule along
        its bone; its spring pulls toward the animated pose (qpos_spring set each step), stiffness per link;
        chains collide with the drivers' capsules and the floor, never with each other

Contacts a chain's capsules make with body capsules in the animated pose itself (a tail's root inside the hips, an
ear's inside the head) are excluded: the animation keeps them there, the simulation could only fight it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jiggle.rig.motion import quat

ANCHOR_TIMECONST = 0.01
"""seconds: 1 / the angular frequency of the anchor's springs to the animated pose (critically damped; >= 2 steps,
so the explicit spring stays well inside the step's stability)."""
CONTACT_TIMECONST = 0.01
"""seconds: the softness of a chain's contacts (MuJoCo solref)."""
LIMIT_TIMECONST = 0.05
"""seconds: the softness of a joint's limit: a spring that grows past it, not a wall."""
MARGIN = 0.1
"""A link's contact margin, in its radius: contacts act before the capsules touch."""
ANCHOR_MASS = 20.0
"""The anchor's mass over its chains' (its rotational inertia: that mass at the body's size, so the chains' pull
on it is as small a share in any unit)."""
ARMATURE = 0.2
"""Each ball joint's armature (rotor inertia) in the inertia it turns: it keeps a light link under a strong joint
from ringing far faster than the chain swings (the step follows the fastest local mode), at the cost of a few
percent of slowing on the light tips. Part of the model: the reference in the tests uses it as well."""
STEP_PER_PERIOD = 8.0
"""Steps per period of the fastest local mode, at least."""
DT_RANGE = (1.0 / 4000.0, 1.0 / 200.0)
"""seconds: the step's range (at most half the anchor's and the contacts' time constants)."""


@dataclass(frozen=True, eq=False)
class ChainModel:
    """The compiled model and where everything sits in it.

    model : mujoco.MjModel. links : rig.character.chains.ChainLinks. drivers : (D,) the character's joints posed
    from the animation: first the chains' anchors (A of them: heavy bodies on springs, driven by force), then the
    joints whose capsules they can reach (mocap bodies). ball_q, ball_v : (n,) qpos and dof addresses of each
    link's ball joint. driver_q, driver_v : (A,) of each anchor's joints (7 qpos: position, quaternion; 6 dofs:
    world velocity, local angular velocity, as a free joint's). anchor_mass, anchor_inertia : kg, kg m^2 of each
    anchor. mocap : (D - A,) the mocap index of each driver after the anchors (0, 1, ...: in order). inertia : (n,) kg m^2, what each link's joint turns
    (the link and everything below it, about the joint). own : (n,) kg m^2, the link alone. limit : (n,) radians,
    each joint's soft limit. excluded : set of (link, capsule body) pairs that never collide. dt : seconds.
    """

    model: object
    links: object
    drivers: np.ndarray
    ball_q: np.ndarray
    ball_v: np.ndarray
    driver_q: np.ndarray
    driver_v: np.ndarray
    mocap: np.ndarray
    anchor_mass: float
    anchor_inertia: float
    inertia: np.ndarray
    own: np.ndarray
    limit: np.ndarray
    excluded: frozenset
    dt: float
    capsules: object = None
    floor: float | None = None
    size: float = 2.0


def link_inertia(links) -> tuple[np.ndarray, np.ndarray]:
    """((n,) the inertia each joint turns: every link at and below it about the joint, (n,) each link's own
    about its joint), kg m^2, at bind; a link is a rod of its mass along its bone."""
    n = links.count
    world = np.zeros((n, 4, 4))
    for i in range(n):          # parents first: bind transforms in the chain's root frame
        world[i] = links.local[i] if links.parent[i] < 0 else world[links.parent[i]] @ links.local[i]
    a = world[:, :3, 3]
    b = np.einsum("nij,nj->ni", world[:, :3, :3], links.tip) + a
    own = links.mass * np.einsum("ni,ni->n", b - a, b - a) / 3.0
    total = own.copy()
    for i in range(n):
        k = links.parent[i]
        while k >= 0:           # link i about each joint above it: a rod from a to b seen from joint k
            p = a[k]
            u, v = a[i] - p, b[i] - p
            total[k] += links.mass[i] * (u @ u + u @ v + v @ v) / 3.0
            k = links.parent[k]
    return total, own


def gravity_at(size: float) -> float:
    """m/s^2: the gravity a body `size` metres big swings its chains under: g at sim.chain.params.REFERENCE_SIZE,
    scaled with the size, so a chain swings alike in any unit (its springs are set alike, params)."""
    from jiggle.sim.chain.params import G, REFERENCE_SIZE
    return G * size / REFERENCE_SIZE


def build(links, capsules=None, floor: float | None = None, frequency_hi: float = 1.0, exclude=(),
          limits=None, timestep: float | None = None, size: float = 2.0, bind_world=None) -> ChainModel:
    """The chain model (module docstring).

    links : ChainLinks. capsules : rig.character.capsules.BoneCapsules of the body (None: no body contacts); the
    capsules of chain joints are left out (the links are theirs). floor : metres, the floor's z, or None.
    frequency_hi : Hz, the fastest spring frequency any link will be given (sets the step). exclude : pairs
    (link index, character joint) never to collide. limits : (n,) radians, each joint's soft limit from bind
    (None: none). timestep : seconds, the step (None: from the fastest local mode). size : metres, the body's
    size (gravity_at). bind_world : (J, 4, 4) the character's bind pose, to keep only the capsules a chain can
    reach (None: every capsule).
    """
    import mujoco
    n = links.count
    inertia, own = link_inertia(links)
    # the fastest local mode: a joint's spring (set over what it turns) acting on its own link alone
    hi = frequency_hi * float(np.sqrt(np.max(inertia / (own + ARMATURE * inertia)))) if n else 1.0
    dt = timestep or float(np.clip(1.0 / (STEP_PER_PERIOD * hi), *DT_RANGE))
    anchors = np.unique(links.anchor[links.anchor >= 0])
    chain_joints = set(int(j) for j in links.joints)
    reach = _reachable(links, capsules, chain_joints, bind_world)
    statics = np.array([j for j in reach if j not in set(anchors.tolist())], np.int64)
    drivers = np.r_[anchors, statics].astype(np.int64)
    f = lambda v: " ".join(f"{x:.9g}" for x in np.ravel(v))   # noqa: E731
    xml = [f'<mujoco model="chains"><compiler angle="radian" autolimits="true"/>'
           f'<option timestep="{dt:.9g}" integrator="Euler" gravity="0 0 {-gravity_at(size):.9g}" '
           'iterations="30" tolerance="1e-7"/>'
           '<worldbody>']
    if floor is not None:
        xml.append(f'<geom name="floor" type="plane" pos="0 0 {floor:.9g}" size="0 0 1" contype="0" conaffinity="1"/>')
    children = [[] for _ in range(n)]
    for i in range(n):
        if links.parent[i] >= 0:
            children[links.parent[i]].append(i)
    lim = np.full(n, np.pi) if limits is None else np.asarray(limits, np.float64)

    def link(i: int) -> str:
        T = links.local[i]
        q = quat.normalize(quat.from_matrix(T[:3, :3]))
        r, tip = float(links.radius[i]), links.tip[i]
        rng = f' range="0 {lim[i]:.9g}" solreflimit="{LIMIT_TIMECONST} 1"' if lim[i] < np.pi - 1e-6 else ""
        geom = (f'<geom type="capsule" fromto="0 0 0 {f(tip)}" size="{r:.9g}" mass="{links.mass[i]:.9g}" '
                f'contype="1" conaffinity="0" margin="{MARGIN * r:.9g}" solref="{CONTACT_TIMECONST} 1" '
                'friction="0.3 0.005 0.0001"/>') if np.linalg.norm(tip) > 1e-9 else \
            f'<inertial pos="0 0 0" mass="{links.mass[i]:.9g}" diaginertia="{f([1e-6] * 3)}"/>'
        # gravcomp: a chain's gravity share is set per step (1 - share); MuJoCo applies it only to a model compiled
        # with some gravcomp, so each link starts with a negligible one
        return (f'<body name="link{i}" pos="{f(T[:3, 3])}" quat="{f(q)}" gravcomp="1e-9">'
                f'<joint name="ball{i}" type="ball" armature="{ARMATURE * inertia[i]:.9g}"{rng}/>'
                + geom + "".join(link(k) for k in children[i]) + "</body>")
    heavy = ANCHOR_MASS * float(links.mass.sum()) if n else 1.0
    turn = heavy * size * size
    w = 1.0 / ANCHOR_TIMECONST
    spring = lambda mass: f'stiffness="{mass * w * w:.9g}" damping="{2.0 * mass * w:.9g}"'    # noqa: E731
    def geoms(j) -> list[str]:
        out = []
        if capsules is not None and int(j) in set(reach.tolist()):
            for c in np.flatnonzero(capsules.joint == j):
                a, b = capsules.local[c]
                shape = f'type="sphere" pos="{f(a)}"' if np.linalg.norm(b - a) < 1e-9 else \
                    f'type="capsule" fromto="{f(a)} {f(b)}"'
                out.append(f'<geom {shape} size="{capsules.radius[c]:.9g}" contype="0" conaffinity="1" mass="0"/>')
        return out
    for j in anchors:
        # gravcomp 1: the anchor holds its own weight, so its driving force is its mass times the acceleration
        xml.append(f'<body name="driver{j}" gravcomp="1">'
                   + "".join(f'<joint name="{a}{j}" type="slide" axis="{ax}" {spring(heavy)}/>'
                             for a, ax in (("tx", "1 0 0"), ("ty", "0 1 0"), ("tz", "0 0 1")))
                   + f'<joint name="turn{j}" type="ball" {spring(turn)}/>'
                   f'<inertial pos="0 0 0" mass="{heavy:.9g}" diaginertia="{f([turn] * 3)}"/>')
        xml.extend(geoms(j))
        xml.extend(link(i) for i in np.flatnonzero(links.anchor == j))
        xml.append('</body>')
    for j in statics:
        xml.append(f'<body name="target{j}" mocap="true">')
        xml.extend(geoms(j))
        xml.append('</body>')
    xml.append('</worldbody><contact>')
    excluded = set()
    for i, j in exclude:
        if int(j) in set(reach.tolist()):
            excluded.add((int(i), int(j)))
            xml.append(f'<exclude body1="link{i}" body2="{"driver" if j in set(anchors.tolist()) else "target"}{j}"/>')
    xml.append('</contact></mujoco>')
    model = mujoco.MjModel.from_xml_string("".join(xml))
    jid = lambda name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)   # noqa: E731
    bid = lambda name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)    # noqa: E731
    ball = [jid(f"ball{i}") for i in range(n)]
    free = [jid(f"tx{j}") for j in anchors]      # the first of its joints: x, y, z, then the ball
    return ChainModel(
        model=model, links=links, drivers=drivers,
        ball_q=np.array([model.jnt_qposadr[k] for k in ball], np.int64),
        ball_v=np.array([model.jnt_dofadr[k] for k in ball], np.int64),
        driver_q=np.array([model.jnt_qposadr[k] for k in free], np.int64),
        driver_v=np.array([model.jnt_dofadr[k] for k in free], np.int64),
        mocap=np.array([model.body_mocapid[bid(f"target{j}")] for j in statics], np.int64),
        anchor_mass=heavy, anchor_inertia=turn,
        inertia=inertia, own=own, limit=lim, excluded=frozenset(excluded), dt=dt, capsules=capsules, floor=floor,
        size=size)


def _reachable(links, capsules, chain_joints: set, bind_world: np.ndarray | None) -> np.ndarray:
    """The joints (not chain joints) with a capsule some chain can reach at bind: nearer its root's joint than the
    chain's length and thickest link; every joint with a capsule when the bind pose is not given."""
    if capsules is None or not capsules.count or not links.count:
        return np.zeros(0, np.int64)
    if bind_world is None:
        return np.unique([j for j in capsules.joint if int(j) not in chain_joints]).astype(np.int64)
    from jiggle.sim.chain.measure import segment_distances
    out = set()
    for c in range(capsules.count):
        j = int(capsules.joint[c])
        if j in chain_joints or j in out:
            continue
        a, b = ((bind_world[j] @ np.append(e, 1.0))[:3] for e in capsules.local[c])
        for i in np.flatnonzero(links.parent < 0):
            ch = links.chain == links.chain[i]
            p = bind_world[links.joints[i]][:3, 3]
            reach = links.length[links.chain[i]] + 2.0 * links.radius[ch].max() + capsules.radius[c]
            if segment_distances(p, p, a, b) <= reach:
                out.add(j)
                break
    return np.array(sorted(out), np.int64)
