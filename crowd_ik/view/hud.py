"""The game's HUD text: time scale, frame, hits, dodges, who is standing, and the IK line."""

from __future__ import annotations


def hud_lines(world) -> list[str]:
    """Lines drawn top-left. The IK line shows the solver and its iterations, or with
    world.hud_timings the smoothed IK and simulation milliseconds (which differ run to run)."""
    counts = f"hits {world.hits}   dodges {world.dodges}   standing {int(world.characters.alive.sum())}/{world.n}"
    if world.n_shooters:
        counts += f"   shooters down {world.shooters_down}/{world.n_shooters}"
    if world.open_ended:  # a live session has no set length
        frame = f"frame {world.frame}   world {world.world_time:.2f} s   shots {world.player.shots}"
    else:
        frame = f"frame {world.frame}/{world.scene.n_frames}   world {world.world_time:.2f} s"
    lines = [f"TIME x{world.time_scale:.2f}", frame, counts]
    bodies = world.n + world.n_shooters + 1
    if world.hud_timings and world.hud_ms["ik"] is not None:
        lines.append(f"IK {world.hud_ms['ik']:.1f} ms   sim {world.hud_ms['simulation']:.1f} ms   ({bodies} bodies)")
    else:
        lines.append(f"IK {world.scene.solver.method} x{world.scene.solver.iterations}   ({bodies} bodies)")
    return lines
