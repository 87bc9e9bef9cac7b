"""Bullet physics: semi-implicit Euler with gravity and quadratic drag, spawning into slots, copying out."""

import taichi as ti

ndarray = ti.types.ndarray
vec3 = ti.math.vec3


@ti.func
def integrate_bullet(i, pos: ti.template(), vel: ti.template(), age: ti.template(), alive: ti.template(),
                     prev: ti.template(), dt, gravity, drag, lifetime, far):
    """integrate_bullets for bullet i (the loop bodies here are functions, so that fused kernels
    share them: a loop inside a ti.func runs serially, only a kernel's top-level loops are parallel)."""
    if alive[i] != 0:
        x = pos[i]
        prev[i] = x
        w = vel[i] + vec3(0.0, -gravity, 0.0) * dt
        v = w / (1.0 + drag * w.norm() * dt)
        x = x + v * dt
        pos[i] = x
        vel[i] = v
        a = age[i] + dt
        age[i] = a
        if a > lifetime or x[1] < -1.0 or x.norm() > far:
            alive[i] = 0


@ti.kernel
def integrate_bullets(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    age: ndarray(ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    prev: ndarray(dtype=vec3, ndim=1),
    dt: float,
    gravity: float,
    drag: float,
    lifetime: float,
    far: float,
):
    """One step of every live bullet (pos, vel, prev: (P, 3); age: (P,) s; alive: (P,) 0/1).

    prev <- pos (the start of this step's swept segment), then semi-implicit Euler:
        w = v + g dt                       g = (0, -gravity, 0) m/s^2
        v' = w / (1 + drag |w| dt)         quadratic drag dv/dt = -drag |v| v, drag in 1/m
        x' = x + v' dt
    The drag update is implicit in the speed, so it never reverses a bullet however large
    drag |v| dt is (the explicit v -= drag |v| v dt does once drag |v| dt > 1). age += dt; a bullet
    dies when age > lifetime, y < -1 m or |x| > far. A bullet killed here is not tested for hits
    on this step's segment.
    """
    for i in range(pos.shape[0]):
        integrate_bullet(i, pos, vel, age, alive, prev, dt, gravity, drag, lifetime, far)


@ti.kernel
def spawn_bullets(
    slots: ndarray(dtype=ti.i32, ndim=1),
    origins: ndarray(dtype=vec3, ndim=1),
    velocities: ndarray(dtype=vec3, ndim=1),
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    age: ndarray(ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    prev: ndarray(dtype=vec3, ndim=1),
    count: ti.i32,
    serial: ti.template(),
):
    """Bullet k < count (origins, velocities: (K, 3), K >= count) goes live in slot slots[k] (K,) with age 0,
    prev = pos. The slots are distinct, so the loop's order does not matter (serial: on the launching thread)."""
    ti.loop_config(serialize=serial)
    for k in range(count):
        s = slots[k]
        pos[s] = origins[k]
        prev[s] = origins[k]
        vel[s] = velocities[k]
        age[s] = 0.0
        alive[s] = 1


@ti.kernel
def export_bullets(
    pos: ndarray(dtype=vec3, ndim=1),
    vel: ndarray(dtype=vec3, ndim=1),
    alive: ndarray(dtype=ti.i32, ndim=1),
    pos_out: ndarray(dtype=vec3, ndim=1),
    vel_out: ndarray(dtype=vec3, ndim=1),
    alive_out: ndarray(dtype=ti.i32, ndim=1),
):
    """pos_out, vel_out (P, 3) <- pos, vel; alive_out (P,) <- alive: the pool's state copied out in
    one launch (the outputs are usually host NumPy arrays)."""
    for p in range(pos.shape[0]):
        pos_out[p] = pos[p]
        vel_out[p] = vel[p]
        alive_out[p] = alive[p]
