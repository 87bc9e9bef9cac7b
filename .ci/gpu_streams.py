"""Time chain16 FABRIK (the bench's workload, from straight, tolerance 1.6 mm, 100 iterations) with several counts
of the free lanes' GPU streams (kernels/lane_plan.GPU_STREAMS) in one process: more streams fill more of the GPU,
fewer keep the joint-major scratch in L2. Part of .ci/cuda-check (step `streams`).

Usage: python .ci/gpu_streams.py [--arch cuda|cpu] [--chars N] [--streams 32768,65536,...]
(--arch cpu: a dry run of the same code path at one lane on the CPU, with small counts)
"""

import argparse
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="cuda", choices=("cuda", "cpu"))
    ap.add_argument("--chars", type=int, default=1_000_000)
    ap.add_argument("--streams", default="32768,65536,131072,262144")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()

    import crowd_ik as cik

    cik.init(arch=args.arch, lanes=1)
    from crowd_ik.bench import workloads as w
    from crowd_ik.kernels import lane_plan
    from crowd_ik.solvers import settings

    if args.arch == "cpu":  # the GPU's stream counts on the CPU (a dry run)
        settings.set_lanes(1, "cuda")
    wl = w.make_workload("chain16", args.chars)
    crowd = cik.Crowd(wl.rig, wl.n, spacing=w.SPACING)
    for streams in (int(s) for s in args.streams.split(",")):
        lane_plan.GPU_STREAMS = streams
        times = []
        for k in range(args.repeats + 1):  # the first call compiles
            crowd.set_angles(wl.angles)
            t0 = time.perf_counter()
            rep = crowd.solve(wl.targets, method="fabrik", max_iterations=wl.max_iterations, tolerance=wl.tolerance)
            times.append(time.perf_counter() - t0)
        print(f"streams {streams:>7}: best {min(times[1:]) * 1e3:7.2f} ms  first {times[0]:6.2f} s  "
              f"success {np.mean(rep.converged) * 100:.3f} %  mean it {rep.iterations.mean():.2f}", flush=True)


if __name__ == "__main__":
    main()
