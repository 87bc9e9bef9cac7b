"""Counter-based random numbers for kernels: a pure function of (seed, index, counter).

Every draw is the PCG hash (Jarzynski & Olano, "Hash Functions for GPU Rendering", JCGT 9(3), 2020)
applied three times, folding in one integer at a time:

    hash_u32(seed, index, counter) = pcg(pcg(pcg(seed) + index) + counter)     (uint32, wrapping)

so a draw never depends on thread scheduling or on how many draws other threads made. `index` is
the item (character, shooter, bullet slot) and `counter` the frame or draw number. The NumPy twin
`crowd_ik.geometry.rng` is bit-identical.
"""

import taichi as ti

ndarray = ti.types.ndarray

_INV_2_24 = 1.0 / 16777216.0


@ti.func
def pcg(v):
    """PCG RXS-M-XS output permutation of one uint32 (a bijection on 32-bit words)."""
    state = ti.cast(v, ti.u32) * ti.u32(747796405) + ti.u32(2891336453)
    word = ((state >> ((state >> ti.u32(28)) + ti.u32(4))) ^ state) * ti.u32(277803737)
    return (word >> ti.u32(22)) ^ word


@ti.func
def hash_u32(seed, index, counter):
    """uint32 hash of three integers (any integer type; negative values wrap as two's complement)."""
    h = pcg(ti.cast(seed, ti.u32))
    h = pcg(h + ti.cast(index, ti.u32))
    return pcg(h + ti.cast(counter, ti.u32))


@ti.func
def uniform(seed, index, counter):
    """f32 in [0, 1): the top 24 bits of hash_u32 times 2^-24 (exact in float32)."""
    return ti.cast(hash_u32(seed, index, counter) >> ti.u32(8), ti.f32) * ti.f32(_INV_2_24)


@ti.kernel
def fill_hash(
    seed: ndarray(dtype=ti.u32, ndim=1),
    index: ndarray(dtype=ti.u32, ndim=1),
    counter: ndarray(dtype=ti.u32, ndim=1),
    out: ndarray(dtype=ti.u32, ndim=1),
):
    """out[i] = hash_u32(seed[i], index[i], counter[i]); all (n,) uint32."""
    for i in range(out.shape[0]):
        out[i] = hash_u32(seed[i], index[i], counter[i])


@ti.kernel
def fill_uniform(
    seed: ndarray(dtype=ti.u32, ndim=1),
    index: ndarray(dtype=ti.u32, ndim=1),
    counter: ndarray(dtype=ti.u32, ndim=1),
    out: ndarray(dtype=ti.f32, ndim=1),
):
    """out[i] = uniform(seed[i], index[i], counter[i]); inputs (n,) uint32, out (n,) float32 in [0, 1)."""
    for i in range(out.shape[0]):
        out[i] = uniform(seed[i], index[i], counter[i])
