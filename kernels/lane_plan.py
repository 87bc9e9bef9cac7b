"""How the lane-packed kernels split a crowd: packets, streams, lanes per stream and scratch capacity.

Plain Python (no Taichi state until lane_rows is called): kernels/fabrik_lanes.py and kernels/dls_lanes.py
size their scratch fields and launches with these, and Crowd passes the stream count to them.
"""

MAX_STREAMS = 256  # streams per launch (the scratch fields hold this many; larger crowds get longer streams)
# On CUDA (one lane) each stream is a GPU thread: enough to fill an H100 or H200 (132 SMs x 1,024 resident threads)
# with some to spare, so a million characters make streams of about 8 (a warp's threads then run similar totals of
# iterations)
GPU_STREAMS = 1 << 17
CHARS_PER_LANE = 32  # characters a stream's lane works through on average (more streams balance threads)


def packets(n: int, lanes: int) -> int:
    """Packets of `lanes` consecutive characters that hold n characters (the last one padded)."""
    return (n + lanes - 1) // lanes


def pass_lanes(lanes: int) -> int:
    """Lanes per stream of FABRIK's passes for the machine's vector width: two vectors per value, at most 32.
    Each joint's update is a dependent chain of square roots and divisions; two independent halves hide its
    latency (chain16, 16,384 characters, AVX-512: 8.6 -> 7.1 ms). (DLS keeps one vector per value: at 2L it
    ran 12 % faster but compiled in 31 s instead of 10 s.)"""
    return min(2 * lanes, 32)


def capacity(n: int) -> int:
    """The scratch fields' rows for n joints or effectors: the next power of two, at least 4 (a kernel per
    size class)."""
    return 1 << max(2, (n - 1).bit_length())


def streams(n: int, lanes: int, serial: bool = False) -> int:
    """Streams for n characters: about CHARS_PER_LANE characters per lane, at least as many as packets up to 8
    (small crowds still use every thread), at most MAX_STREAMS; one for a launch that runs on one thread
    (kernels/serial_loops.py): its lanes then refill from every character, and the work is the crowd's total
    iterations over the lanes plus one tail instead of a tail per stream (chain16 FABRIK on one thread, 100 / 480
    characters, 4 / 8 streams -> 1: 146 -> 90 / 314 -> 233 us)."""
    if serial:
        return 1
    return max(1, min(packets(n, lanes), max(8, packets(n, lanes * CHARS_PER_LANE)), MAX_STREAMS))


def stream_rows(lanes: int, streams: int, rows: int, count: int, joint_major: bool) -> list:
    """`count` scratch fields of `lanes`-wide float32 vectors over (streams, rows). Stream-major (a stream's rows
    together: one CPU thread's packet in its own cache lines) or joint-major, for CUDA: one row of every stream
    together, so the 32 threads of a warp (32 consecutive streams) read a joint in one coalesced access instead of
    32 scattered cache lines."""
    import taichi as ti

    order = "ji" if joint_major else None
    return [ti.Vector.field(lanes, ti.f32, shape=(streams, rows), order=order) for _ in range(count)]


def lane_rows(lanes: int, shape: tuple, count: int) -> list:
    """`count` scratch fields of `lanes`-wide float32 vectors over `shape`, interleaved: one dense SNode holds
    all of them at each index, so a stream's values for one joint share a few cache lines. As separate fields
    each was a power-of-two number of bytes long, so the values of one index sat at the same address modulo
    4 KiB in every field: the same L1 set (8-12 ways for 15-29 fields, so they evicted each other) and
    4K-aliased loads and stores (the limited FABRIK lanes' warm 10,000-humanoid solve 14.2 -> 12.7 ms)."""
    import taichi as ti

    fields = [ti.Vector.field(lanes, ti.f32) for _ in range(count)]
    ti.root.dense((ti.i, ti.ij, ti.ijk)[len(shape) - 1], shape).place(*fields)
    return fields
