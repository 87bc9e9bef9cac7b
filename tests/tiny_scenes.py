"""The small scene the command-line tests play: six characters, two fast shooters, a near camera."""


def tiny_scene(frames: int = 12, size: tuple[int, int] | None = (96, 64)) -> str:
    """TOML text of the tiny scene with `frames` video frames at `size` (None: the scene's default size)."""
    video = f"width = {size[0]}, height = {size[1]}, " if size else ""
    return f"""
seed = 3
characters = {{ count = 6, spacing = 1.5 }}
shooters = {{ count = 2, fire_rate = 5.0 }}
bullets = {{ pool_size = 256 }}
time = {{ floor = 0.5 }}
camera = {{ position = [0, 4, 9], look_at = [0, 1, 0], fov_deg = 50 }}
video = {{ {video}fps = 24, frames = {frames} }}
"""
