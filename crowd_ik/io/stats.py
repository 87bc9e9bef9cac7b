"""The numbers of one rendered run: what `play --stats F.json` writes, what render-many records per job in
its manifest, and the one-screen text summary `play` prints.

Kept out of crowd_ik/commands/ so that library code (the render-many worker) can build the same record
without importing a command module.
"""

from __future__ import annotations

from crowd_ik import runtime
from crowd_ik.scene import Scene


def summary(world, scene: Scene, out: str, wall_s: float, arch: str, rendered: int, pipeline: dict | None = None) -> dict:
    """The run's numbers (what --stats writes); `pipeline`: io.pipeline.render_video's numbers (the
    video's stages and CPU use), kept under "pipeline"."""
    totals = world.totals
    frames = max(totals["frames"], 1)
    s = world.stats
    info = {
        "scene": scene.name,
        "output": str(out),
        "frames": rendered,
        "size": [scene.video.width, scene.video.height],
        "fps": scene.video.fps,
        "characters": scene.characters.count,
        "standing": s["standing"],
        "shooters": scene.shooters.count,
        "shooters_down": s["shooters_down"],
        "shots": s["shots"],
        "hits": s["hits"],
        "dodges": s["dodges"],
        "world_time_s": s["world_time"],
        "world_steps": s["steps"],
        "solver": scene.solver.method,
        "mean_simulation_ms": totals["simulation_ms"] / frames,
        "mean_ik_ms": totals["ik_ms"] / frames,
        "mean_render_ms": totals["render_ms"] / max(totals["rendered"], 1),
        "wall_s": wall_s,
        "arch": arch,
        "threads": runtime.current().get("threads"),
        "seed": scene.seed,
    }
    if pipeline is not None:
        info["pipeline"] = pipeline
    return info


def format_summary(info: dict) -> str:
    """The one-screen text summary."""
    w, h = info["size"]
    down = info.get("shooters_down", 0)
    return "\n".join([
        f"{info['scene']}: {info['frames']} frames, {w}x{h} at {info['fps']:g} fps -> {info['output']}",
        f"  characters  {info['characters']} ({info['standing']} standing), shooters {info['shooters']}"
        f"{f' ({down} down)' if down else ''}, "
        f"shots {info['shots']}",
        f"  hits        {info['hits']}",
        f"  dodges      {info['dodges']}",
        f"  per frame   simulation {info['mean_simulation_ms']:.1f} ms, IK {info['mean_ik_ms']:.1f} ms "
        f"({info['solver']}), render {info['mean_render_ms']:.1f} ms",
        f"  world time  {info['world_time_s']:.2f} s in {info['world_steps']} steps",
        f"  wall time   {info['wall_s']:.1f} s on {info['arch']}",
        *_pipeline_lines(info.get("pipeline")),
    ])


def _pipeline_lines(p: dict | None) -> list[str]:
    """The video's stages (ms per frame) and CPU use, when render_video's numbers are there."""
    if not p:
        return []
    st = p["stages_ms"]
    render_cpu = p.get("render_cpu_s", 0.0)
    total_cpu = p["cpu_s"] + render_cpu + p["encoder_cpu_s"]
    where = f", drawing {render_cpu:.1f} s" if render_cpu else ""
    return [(f"  video       {p['fps']:.1f} frames/s ({p['mode']}), CPU {p['cpu_percent']:.0f} % "
             f"(encoder {p['encoder_cpu_s']:.1f} s{where} of {total_cpu:.1f} s)"),
            (f"  stages      simulate {st['simulate']:.1f}, draw {st['draw']:.1f} (primitives {st['primitives']:.1f}, "
             f"raster {st['raster']:.1f}), overlay {st['overlay']:.1f}, write {st['write']:.1f}, "
             f"wait {st['wait']:.1f} ms a frame")]

__all__ = ["summary", "format_summary"]
