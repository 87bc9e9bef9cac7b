"""A World played frame by frame: "video frame k shows the world after k steps", written once.

:func:`frames` yields the world at each video frame of a headless run (scripted path, or one
recorded input row per frame through a :class:`Session`); `crowd-ik play`, `--clip`, `export` and
the bench all step a world through it. A :class:`Session` applies one player input
(World.set_player_input) and one World.step(); the same code runs live and replayed.
"""

from __future__ import annotations

from collections.abc import Iterator

from crowd_ik.io.inputs import PlayerInput


class Session:
    """A World played by inputs: each :meth:`advance` applies one input and simulates one video
    frame; the canonical inputs applied are kept in `log` (what --record writes)."""

    def __init__(self, world):
        if world.frame != 0:
            raise ValueError(f"Session: expected a fresh World at frame 0 (got frame {world.frame})")
        self.world = world
        self.log: list[PlayerInput] = []

    def advance(self, inp: PlayerInput) -> None:
        inp = inp.canonical()
        self.world.set_player_input(inp.move, inp.aim, inp.fire)
        self.world.step()
        self.log.append(inp)

    def frame(self, inp: PlayerInput):
        """Apply `inp`, simulate one video frame and render it: (H, W, 3) uint8 BGR."""
        self.advance(inp)
        return self.world.render()


def frames(world, count: int, inputs=None) -> Iterator[int]:
    """Step `world` through video frames 0..count-1, yielding k when the world shows frame k.

    Without inputs frame k is the world after k steps (frame 0: the start); with inputs (a sequence
    of PlayerInput, one per frame) frame k is the world after input row k was applied and stepped.
    """
    session = Session(world) if inputs is not None else None
    for k in range(count):
        if session is not None:
            session.advance(inputs[k])
        elif k:
            world.step()
        yield k
