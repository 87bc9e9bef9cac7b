"""`crowd-ik scenes [FILE]`: list the shipped scenes, or check one and print its effective values as TOML."""

from __future__ import annotations

from pathlib import Path

from crowd_ik.scene import load_scene, shipped_scenes
from crowd_ik.scene_checks import _gib, memory_estimate

# --------------------------------------------------------------------------------------------
# `crowd-ik scenes [FILE]`


def describe(path: Path) -> str:
    """The first comment line of a scene file, without the '#'."""
    for line in path.read_text(encoding="utf-8").splitlines():
        s = line.strip()
        if s.startswith("#"):
            return s.lstrip("#").strip()
        if s:
            break
    return ""


def scene_table(paths: list[Path]) -> str:
    """A text table of scenes: name, characters, shooters, frames, size, description."""
    scenes = [(load_scene(p), describe(p)) for p in paths]
    scenes.sort(key=lambda s: (s[0].characters.count, s[0].name))
    header = ("name", "characters", "shooters", "frames", "size", "description")
    rows = [header] + [
        (s.name, str(s.characters.count), str(s.shooters.count), str(s.n_frames),
         f"{s.video.width}x{s.video.height}", d)
        for s, d in scenes
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(len(header) - 1)]
    right = {1, 2, 3}
    lines = []
    for r in rows:
        cells = [c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(r, widths))]
        lines.append("  ".join(cells) + "  " + r[-1])
    return "\n".join(lines)


def run(args) -> int:
    """`crowd-ik scenes`: table of the shipped scenes; `crowd-ik scenes FILE`: check one."""
    if args.file is None:
        paths = shipped_scenes()
        if not paths:
            raise RuntimeError("no shipped scenes found (looked beside the package and in crowd_ik/scenes)")
        print(scene_table(paths))
        print(f"\n{len(paths)} scenes in {paths[0].parent}; check one with: crowd-ik scenes FILE")
        return 0
    scene = load_scene(args.file)
    need = memory_estimate(scene)
    print(f"{args.file}: ok")
    print(f"# {scene.name}: {scene.n_frames} frames, estimated memory {_gib(need['total'])}")
    print(scene.to_toml(), end="")
    return 0
