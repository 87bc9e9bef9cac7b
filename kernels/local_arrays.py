"""Rows of per-character local arrays (ti.Matrix of n_joints x 3 or x 4, a compile-time size) as vectors.

The solvers keep each character's pose in such arrays while they iterate: a store to an ndarray makes
LLVM reload the array's shape and pointer (they may alias), about 7 integer instructions per float
stored, while a local array lives on the thread's stack (kernels/dls_free.py has the measurements).
"""

import taichi as ti

vec3 = ti.math.vec3
vec4 = ti.math.vec4


@ti.func
def get4(m: ti.template(), j):
    return vec4(m[j, 0], m[j, 1], m[j, 2], m[j, 3])


@ti.func
def get3(m: ti.template(), j):
    return vec3(m[j, 0], m[j, 1], m[j, 2])


@ti.func
def put(m: ti.template(), j, v):
    for c in ti.static(range(v.n)):
        m[j, c] = v[c]
