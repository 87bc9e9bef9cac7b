"""The numbers of one rendered run: what `play --stats F.json` writes, what render-many records per job in
its manifest, and the one-screen text summary `play` prints.

Kept out of crowd_ik/commands/ so that library code (the render-many worker) can build the same record
without importing a command module.
"""

from __future__ import annotations

from crowd_ik import runtime
from crowd_ik.scene import Scene


def summary(world, scene: Scene, out: str, wall_s: float, arch: str, rendered: int) -> dict:
    """The run's numbers (what --stats writes)."""
    totals = world.totals
    frames = max(totals["frames"], 1)
    s = world.stats
    return {
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
    ])


__all__ = ["summary", "format_summary"]
