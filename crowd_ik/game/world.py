"""World: the SUPERHOT-style crowd game - characters, shooters, the player, bullets, shards - in a fixed order.

`World(scene)` owns its parts, all allocated once: `characters` (game.characters), `shooters`
(game.shooters), `player` (game.player), `bullets` (game.bullets: the one owner of every slot and
every hit) and `shards` (game.shards), plus the camera. `step()` advances one video frame,
`render()` draws it. Without a hand on the controls (a headless render) the player is driven by the
autopilot (game.autopilot: it walks the path, stops, aims and shoots); `set_player_input` (live
play, recorded inputs) switches it off for good; `autopilot=False` walks the path as scripted
(game.player.Walker). The camera (view.camera.CameraRig) follows the player or stays fixed.

Time (DESIGN "Game rules"). The player walks its path in *real* (video) time, pausing at every
corner. The time scale s follows the player's speed with a first-order response,
    ds/dt = response * (s_target - s),   s_target = floor + (1 - floor) * min(1, speed / player.speed),
and a video frame covers s / fps seconds of *world* time. The world always advances in fixed steps
of DT seconds: the frame's world time goes into an accumulator and whole steps are taken out of it,
so a frame in slow motion may take no step at all; `render()` then draws the state interpolated
between the last two steps (alpha = accumulator / DT), so slow motion stays smooth.

One world step (`step_world`), in this order:
  1. shooters aim and fire when due;
  2. characters turn threats into dodges (and flee), then walk: wander, keep apart from everybody
     (the player and the shooters included), step their feet (game.crowd_motion, game.gait);
  3. IK for characters, then shooters (one batched solve each; legs planted analytically);
  4. bullets move and hit characters (hit ones shatter), then the player's bullets hit shooters;
  5. shards move.
No Python loop runs over characters. Reproducible: the same scene, seed and frame count give the
same frames (the HUD shows measured milliseconds only with hud_timings=True).
"""

from __future__ import annotations

import math
import time

import numpy as np

from crowd_ik import runtime
from crowd_ik.game.aim import ballistic_direction, cone_sample  # noqa: F401  (part of the module's API)
from crowd_ik.game.autopilot import Autopilot
from crowd_ik.game.body import Body, make_rig
from crowd_ik.game.bullets import Bullets
from crowd_ik.game.characters import Characters
from crowd_ik.game.layout import character_layout, shooter_layout  # noqa: F401  (part of the module's API)
from crowd_ik.game.player import Player, Walker  # noqa: F401  (part of the module's API)
from crowd_ik.game.shards import Shards
from crowd_ik.game.shooters import COLOR as shooters_color, Shooters
from crowd_ik.rig import Rig
from crowd_ik.scene import Scene

DT = 1.0 / 60.0  # seconds of world time per fixed simulation step
HUD_EMA = 0.1  # smoothing of the HUD's millisecond figures
HUD_TIMINGS = False  # default of World(hud_timings=None): the HUD shows simulation values only, so
# frames are a function of scene, seed and frame count (`play --hud-timings` adds the milliseconds)


class World:
    """The game: characters, shooters, the player, bullets and shards, stepped and drawn.

    autofire=False keeps the shooters aiming but not firing (bullets then come only from `fire`).
    hud_timings=True adds the measured milliseconds to the HUD (frames then differ between runs;
    None: the module default HUD_TIMINGS). open_ended=True is a session with no set length (live
    play, replayed inputs): the HUD's frame line then counts the player's shots instead of a total.
    autopilot=False: the player walks its path as scripted instead of being steered by the autopilot.
    """

    def __init__(self, scene: Scene, autofire: bool = True, hud_timings: bool | None = None,
                 open_ended: bool = False, autopilot: bool = True):
        if not isinstance(scene, Scene):
            raise ValueError(f"World: scene: expected a crowd_ik.Scene (got {type(scene).__name__})")
        runtime.ensure_init()
        from crowd_ik.view.camera import CameraRig

        self.scene = scene
        self.seed = scene.seed
        self.autofire = bool(autofire)
        self.hud_timings = HUD_TIMINGS if hud_timings is None else bool(hud_timings)
        self.open_ended = bool(open_ended)
        N, S = scene.characters.count, scene.shooters.count
        scale = scene.characters.scale
        self.body = Body(make_rig(scene.characters.rig, scale), scale)
        self.hbody = self.body if self.body.humanoid else Body(Rig.humanoid(1.75 * scale), scale)
        self.characters = Characters(self.body, scene)
        self.shooters = Shooters(self.hbody, scene)
        self.shooters.start(self.characters)
        self.player = Player(self.hbody, scene)
        self.autopilot = Autopilot(scene, self.hbody) if autopilot else None
        # bullets: a pool over the arena's extent
        extent = max(float(np.abs(self.characters.roots[:, [0, 2]]).max()) + 2.0 * scene.characters.spacing,
                     float(np.abs(self.shooters.roots[:, [0, 2]]).max()) + 2.0,
                     float(np.abs(np.asarray(scene.player.path)).max()) + 2.0)
        self.bullets = Bullets(scene, extent, capsule_capacity=N * self.body.n_bones)
        self.shards = Shards(Shards.capacity_for([(self.body, N), (self.hbody, S)]), scene.seed, scene.bullets.gravity)

        # clocks and counters
        self.frame = 0
        self.world_time = 0.0
        self.time_scale = scene.time.floor
        self.steps = 0
        self._acc = 0.0
        self._phase_ms = {"simulation": 0.0, "ik": 0.0, "render": 0.0}
        self.last_step_ms = {"ik": 0.0, "bullets": 0.0, "total": 0.0}  # see step_world
        self.totals = {"simulation_ms": 0.0, "ik_ms": 0.0, "render_ms": 0.0, "frames": 0, "rendered": 0}
        self.hud_ms = {"ik": None, "simulation": None}  # smoothed for the HUD

        # drawing
        self.max_capsules = N * self.body.n_bones + S * (self.hbody.n_bones + 1) + self.hbody.n_bones + self.shards.capacity
        self._renderer = None  # made on the first render(): export and timing runs never draw
        self._body_names = None  # primitives()' body names, made on first use
        self._update_player(0.0)
        self.camera_rig = CameraRig(scene.camera, scene.video.width, scene.video.height, self.player.joints[0])

    # ------------------------------------------------------------------ public API
    @property
    def camera(self):
        """This frame's view.render.Camera (it moves with the player in camera.mode "follow")."""
        return self.camera_rig.camera

    @property
    def n(self) -> int:
        return self.characters.n

    @property
    def n_shooters(self) -> int:
        return self.shooters.n

    @property
    def hits(self) -> int:
        """Characters shattered by bullets so far."""
        return self.characters.hits

    @property
    def dodges(self) -> int:
        return self.characters.dodges

    @property
    def shooters_down(self) -> int:
        """How many shooters the player's bullets have downed."""
        return self.shooters.down

    @property
    def stats(self) -> dict:
        """Counters and the last frame's per-phase milliseconds (simulation, IK, render).

        hits and standing count the characters; shooters_down the shooters downed by the player's bullets.
        """
        return {
            "frame": self.frame,
            "world_time": self.world_time,
            "time_scale": self.time_scale,
            "steps": self.steps,
            "hits": self.hits,
            "dodges": self.dodges,
            "shots": int(self.shooters.shots_fired.sum()),
            "standing": int(self.characters.alive.sum()),
            "shooters_down": self.shooters_down,
            "bullets": int(self.bullets.alive.sum()),
            "shards": int(self.shards.live.sum()),
            "simulation_ms": self._phase_ms["simulation"],
            "ik_ms": self._phase_ms["ik"],
            "render_ms": self._phase_ms["render"],
        }

    def joints(self) -> np.ndarray:
        """(N, J, 3) float32 world joint positions of the characters after the last world step."""
        return self.characters.joints.copy()

    def live_bullets(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (K, 3), velocities (K, 3)) of the live bullets after the last world step."""
        return self.bullets.live()

    def fire(self, origins, velocities) -> np.ndarray:
        """Spawn bullets now at origins (K, 3) m with velocities (K, 3) m/s; returns their slots.

        They are nobody's in particular: like the shooters' bullets they hit characters, not shooters
        (only the player's bullets, fired by set_player_input, hit shooters).
        """
        origins = np.asarray(origins, np.float32).reshape(-1, 3)
        velocities = np.asarray(velocities, np.float32).reshape(-1, 3)
        if origins.shape != velocities.shape or not (np.all(np.isfinite(origins)) and np.all(np.isfinite(velocities))):
            raise ValueError(f"fire: origins and velocities must be finite (K, 3) arrays "
                             f"(got {origins.shape} and {velocities.shape})")
        return self.bullets.spawn(origins, velocities)

    def set_player_input(self, move, aim=None, fire: bool = False) -> np.ndarray:
        """Steer the player by hand instead of along its path (live play, recorded inputs).

        move: (x, z) in [-1, 1] world axes (a longer vector is cut to length 1): the player walks
        at move * player.speed in the following step() calls, until the next call (the scripted
        path is not resumed); the time scale follows its speed as before. aim: (3,) world point
        or None: the player turns toward it and IK holds its right hand on the line from the
        shoulder to it. fire: spawn one bullet now from the right hand toward aim (needs aim),
        through the pool like the shooters' bullets; the player's bullets also hit the shooters
        (a shooter hit is down). Returns the pool slots spawned (0 or 1).
        """
        if fire and aim is None:
            raise ValueError("set_player_input: fire needs an aim point (got aim=None)")
        self.autopilot = None  # a hand on the controls: for good
        self.player.steer(move, aim)
        if not fire:
            return np.zeros(0, np.int64)
        return self._player_fire()

    def _player_fire(self) -> np.ndarray:
        """One bullet from the player's right hand toward its aim point; returns the slots spawned."""
        slots = self.bullets.spawn(*self.player.shot(self.scene.bullets), player=True)
        self.player.shots += len(slots)
        return slots

    def step(self) -> None:
        """Advance one video frame: the player walks 1/fps s of real time, the time scale follows it,
        and the world takes as many fixed DT steps as the frame's world time allows."""
        t0 = time.perf_counter()
        self._phase_ms["ik"] = 0.0
        dt_video = 1.0 / self.scene.video.fps
        if self.autopilot is not None:
            move, aim, fire = self.autopilot.update(dt_video, self.player, self.shooters, self.characters)
            self.player.steer(move, aim)
            if fire:
                self._player_fire()
        self._update_player(dt_video)
        t = self.scene.time
        goal = t.floor + (1.0 - t.floor) * min(1.0, self.player.speed / self.scene.player.speed)
        self.time_scale += (goal - self.time_scale) * (1.0 - math.exp(-t.response * dt_video))
        self._acc += self.time_scale * dt_video
        while self._acc >= DT:
            self._acc -= DT
            self.step_world()
        self.camera_rig.update(self.player.joints[0], self.time_scale * dt_video)
        self.frame += 1
        total = 1e3 * (time.perf_counter() - t0)
        self._phase_ms["simulation"] = total - self._phase_ms["ik"]
        self.totals["simulation_ms"] += self._phase_ms["simulation"]
        self.totals["ik_ms"] += self._phase_ms["ik"]
        self.totals["frames"] += 1
        for key in ("ik", "simulation"):
            old = self.hud_ms[key]
            self.hud_ms[key] = self._phase_ms[key] if old is None else old + HUD_EMA * (self._phase_ms[key] - old)

    def step_world(self) -> None:
        """One fixed world step of DT seconds, in the order of the module docstring."""
        chars, shooters, bullets = self.characters, self.shooters, self.bullets
        chars.limbs.begin_step()
        shooters.joints_prev = shooters.joints
        bullets.begin_step()
        self.shards.begin_step()
        t0 = time.perf_counter()
        shot = shooters.aim_and_fire(chars, self.world_time, DT, self.autofire)
        if shot is not None:
            bullets.spawn(*shot)
        chars.dodge(bullets, DT)
        obstacles = np.concatenate([self.player.position()[None, [0, 2]],
                                    shooters.ground[shooters.alive][:, [0, 2]]]).astype(np.float64)
        chars.walk(DT, obstacles)
        t1 = time.perf_counter()
        self._phase_ms["ik"] += chars.solve()
        t2 = time.perf_counter()
        self._phase_ms["ik"] += shooters.solve(DT)
        t3 = time.perf_counter()
        hits = bullets.advance(DT, chars)
        if len(hits.chars):
            hit = hits.chars.astype(np.intp)
            chars.struck(hit)
            self.shards.shatter(self.body, chars.joints[hit], chars.colors[hit], bullets.vel[hits.bullets], hits.points)
        self._hit_shooters()
        t4 = time.perf_counter()
        self.shards.step(DT)
        self.world_time += DT
        self.steps += 1
        # milliseconds of this step: the characters' IK (targets, solve, limb capsules), the bullets' step with
        # its hits, and the whole step
        self.last_step_ms = dict(ik=1e3 * (t2 - t1), bullets=1e3 * (t4 - t3),
                                 total=1e3 * (time.perf_counter() - t0))

    def _hit_shooters(self) -> None:
        """The player's bullets against the standing shooters (game.bullets): a shooter hit shatters."""
        downed = self.bullets.player_hits(self.shooters)
        if downed is not None:
            down, impact, velocity = downed
            self.shooters.struck(down)
            colors = np.broadcast_to(np.float32(shooters_color), (len(down), 3))
            self.shards.shatter(self.hbody, self.shooters.joints[down], colors, velocity, impact)

    def simulate(self, seconds: float) -> None:
        """Advance the world alone by `seconds` of world time (whole DT steps; the player and the
        time scale stay put): for scripted tests and for timing the simulation without rendering."""
        for _ in range(int(round(seconds / DT))):
            self.step_world()

    def _update_player(self, dt: float) -> None:
        t0 = time.perf_counter()
        self.player.update(dt)
        self._phase_ms["ik"] += 1e3 * (time.perf_counter() - t0)

    # ------------------------------------------------------------------ drawing
    def primitives(self) -> dict:
        """What the frame shows, interpolated between the last two world steps (view.frame.primitives),
        plus body_names (N+S+2,): character_i, shooter_k, player, shards."""
        from crowd_ik.view.frame import primitives

        prim = primitives(self, min(max(self._acc / DT, 0.0), 1.0))
        if self._body_names is None:  # built once: 10,000 f-strings cost ~3 ms a frame
            self._body_names = ([f"character_{i}" for i in range(self.n)] + [f"shooter_{k}" for k in range(self.n_shooters)]
                                + ["player", "shards"])
        prim["body_names"] = list(self._body_names)
        return prim

    def hud_lines(self) -> list[str]:
        """The HUD text (view.hud.hud_lines)."""
        from crowd_ik.view.hud import hud_lines

        return hud_lines(self)

    @property
    def renderer(self):
        """The Renderer (its buffers are allocated on first use, sized for the scene's maxima)."""
        if self._renderer is None:
            from crowd_ik.view.render import Renderer

            self._renderer = Renderer(self.camera, self.max_capsules, self.scene.bullets.pool_size)
        return self._renderer

    def render(self) -> np.ndarray:
        """The current frame: (H, W, 3) uint8 BGR."""
        t0 = time.perf_counter()
        self.renderer.camera = self.camera
        prim = self.primitives()
        caps, sph = prim["capsules"], prim["spheres"]
        frame = self.renderer.render(caps["a"], caps["b"], caps["radius"], caps["color"],
                                     sph["center"], sph["radius"], sph["color"],
                                     trails=prim["trails"] if len(prim["trails"]) else None,
                                     hud_lines=self.hud_lines())
        self.record_render(1e3 * (time.perf_counter() - t0))
        return frame

    def record_render(self, ms: float) -> None:
        """Count a frame drawn in `ms` milliseconds of this process's time (render(), or the video pipeline's
        hand-over to its drawing process: io.render_process)."""
        self._phase_ms["render"] = ms
        self.totals["render_ms"] += ms
        self.totals["rendered"] += 1


__all__ = ["World", "DT"]
