"""The bench's `render` workload: the three shipped game scenes rendered to H.264 as `crowd-ik play` does
(the pipeline of crowd_ik.io.pipeline, into a temporary .mp4), in frames per second of wall time, warm.

Scenes and sizes are the play defaults of the issue's targets: arena and crowd_1k at 1280x720,
stress_10k at 640x360. Each scene gets a fresh World that first renders a few frames untimed (kernels
compiled or loaded from the offline cache, buffers touched), then a second World from frame 0 renders
`frames` frames through io.pipeline.render_video (in a drawing process, started before the warm-up,
where play would use one); its numbers (fps, per-stage milliseconds, CPU use) are the record.
`--compare` reports the change of fps per scene, so a slower renderer shows up there.
"""

from __future__ import annotations

import os
import tempfile

# (scene, (width, height)), frames per second goal on a 2-core CPU (issue 20)
RENDER_SCENES = (("arena", (1280, 720), 30.0), ("crowd_1k", (1280, 720), 20.0), ("stress_10k", (640, 360), 10.0))
# untimed frames of the warm-up World: past the first shot (frame 3 in every shipped scene), whose bullet kernels a
# process materialises on first use (Taichi's Python frontend, 1.2-2.8 s even with the offline cache warm); with 3
# the timed run still paid it (arena's 90 frames: 15.0 frames/s)
WARM_FRAMES = 8


def render_scene(name: str, size: tuple[int, int], frames: int) -> dict:
    """Render `frames` frames of shipped scene `name` at `size` after a warm-up; render_video's numbers."""
    from crowd_ik.game.world import World
    from crowd_ik.io.pipeline import render_video, wants_render_process
    from crowd_ik.io.render_process import started_early
    from crowd_ik.io.video import open_sink
    from crowd_ik.scene import load_scene, scene_with
    from crowd_ik.session import frames as step_frames

    w, h = size
    scene = scene_with(load_scene(name), frames=max(frames, WARM_FRAMES), width=w, height=h)
    # as play does: a drawing process (when the pipeline uses one) gets ready during the warm-up
    with started_early(wants_render_process(scene)) as early:
        warm = World(scene)
        for _ in step_frames(warm, WARM_FRAMES):
            warm.render()
        world = World(scene)
        with tempfile.TemporaryDirectory(prefix="crowd-ik-bench-render-") as tmp:
            sink = open_sink(os.path.join(tmp, f"{name}.mp4"), scene.video.fps, size)
            stats = render_video(world, step_frames(world, frames), sink,
                                 render_process=early if early is not None else False)
            stats["bytes"] = os.path.getsize(sink.path)
    return dict(scene=name, size=[w, h], characters=scene.characters.count, **stats)


def render_workload(frames: int) -> list[dict]:
    """Every scene of RENDER_SCENES, `frames` frames each."""
    return [dict(render_scene(name, size, frames), goal_fps=goal) for name, size, goal in RENDER_SCENES]


def format_render(records: list[dict], arch: str) -> list[str]:
    """One line per scene: fps, CPU use and the stages."""
    lines = []
    for r in records:
        st = r["stages_ms"]
        lines.append(f"render {arch} {r['scene']} {r['size'][0]}x{r['size'][1]}: {r['fps']:.1f} frames/s "
                     f"(goal {r['goal_fps']:g}), CPU {r['cpu_percent']:.0f} %, per frame simulate {st['simulate']:.1f}, "
                     f"draw {st['draw']:.1f}, overlay {st['overlay']:.1f}, write {st['write']:.1f}, "
                     f"wait {st['wait']:.1f} ms; encoder {1e3 * r['encoder_cpu_s'] / max(r['frames'], 1):.1f} ms CPU")
    return lines


def render_targets(records: list[dict], arch: str) -> list[dict]:
    """The fps goals as bench targets (met or MISSED in the targets table)."""
    return [dict(arch=arch, name=f"render {r['scene']} {r['size'][0]}x{r['size'][1]}, frames/s", n=r["characters"],
                 value=r["fps"], unit="per_s", goal=f">= {r['goal_fps']:g}/s", met=r["fps"] >= r["goal_fps"])
            for r in records]


def compare_render(old: dict, new: dict) -> list[str]:
    """The change of frames per second per (arch, scene, size) between two bench JSON results."""
    def index(result):
        return {(r["arch"], r["scene"], tuple(r["size"])): r for r in result.get("render") or []
                if isinstance(r, dict) and {"arch", "scene", "size", "fps"} <= set(r)}

    before, after = index(old), index(new)
    lines = []
    for key, r in after.items():
        o = before.get(key)
        if o is None or not o["fps"] > 0:
            continue
        change = 100.0 * (r["fps"] / o["fps"] - 1.0)
        lines.append(f"  render {key[0]} {key[1]} {key[2][0]}x{key[2][1]}: {o['fps']:.1f} -> {r['fps']:.1f} frames/s "
                     f"({change:+.1f}%)")
    return lines


__all__ = ["RENDER_SCENES", "render_scene", "render_workload", "format_render", "render_targets", "compare_render"]
