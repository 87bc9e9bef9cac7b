"""How the lane-packed kernels split a crowd: packets, streams, lanes per stream and scratch capacity.

Plain Python (no Taichi state): kernels/fabrik_lanes.py and kernels/dls_lanes.py size their scratch
fields and launches with these, and Crowd passes the stream count to them.
"""

MAX_STREAMS = 256  # streams per launch (the scratch fields hold this many; larger crowds get longer streams)
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


def streams(n: int, lanes: int) -> int:
    """Streams for n characters: about CHARS_PER_LANE characters per lane, at least as many as packets up to 8
    (small crowds still use every thread), at most MAX_STREAMS."""
    return max(1, min(packets(n, lanes), max(8, packets(n, lanes * CHARS_PER_LANE)), MAX_STREAMS))
