"""Pictures of a world: camera and renderer."""
