"""Warp kernels of the chunk graph (sim/jiggle/graph.py): the device's side of two decisions the plain path made on
the host, so that a chunk's particle stepping reads nothing back.

- any_flag: whether any of the tissue contacts' M near flags is set (the hash grid is built under a conditional
  node on it, where the plain path read the flags back);
- restart_offsets: a run's (re)start on the device: the glued particles (the glue kernel's x, v) moved by the
  quasi-static offset and given the goals' fitted velocity, both computed on the host from the track alone
  (sim.jiggle.simulate.restart), in float64 as the host adds them, so the state equals the plain path's bit for bit.

NumPy references: any_flag is ``flags.any()``; restart_offsets is sim.jiggle.simulate.restart's last line,
``(float32(x + y), float32(where(glued, v, vel)))``.
"""
from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def any_flag(
    # in
    flags: wp.array(dtype=wp.int32), count: int,
    # out
    any_out: wp.array(dtype=wp.int32),
):
    """One thread: any_out[0] = 1 when any of flags[0:count] is not 0, else 0."""
    hit = int(0)
    for m in range(count):
        if flags[m] != 0:
            hit = 1
    any_out[0] = hit


@wp.kernel
def restart_offsets(
    # model
    glued: wp.array(dtype=wp.int32),
    # in: the offsets (N,) metres and the goals' velocities (N,) m/s, float64
    y: wp.array(dtype=wp.vec3d), vel: wp.array(dtype=wp.vec3d),
    # state, in and out: the glued particles
    x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
):
    """Particle i: x = float32(float64(x) + y), v = v where glued else float32(vel)."""
    i = wp.tid()
    x = x_out[i]
    d = y[i]
    x_out[i] = wp.vec3(wp.float32(wp.float64(x[0]) + d[0]), wp.float32(wp.float64(x[1]) + d[1]),
                       wp.float32(wp.float64(x[2]) + d[2]))
    if glued[i] == 0:
        u = vel[i]
        v_out[i] = wp.vec3(wp.float32(u[0]), wp.float32(u[1]), wp.float32(u[2]))
