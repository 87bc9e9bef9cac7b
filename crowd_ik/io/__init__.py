"""Files in and out: atomic no-clobber output, video sinks, motion clips."""
