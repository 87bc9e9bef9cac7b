"""The SUPERHOT-style game: the World and its parts."""
