"""The LeRobot dataset layer: features, adademo metadata, crash-safe appends, integrity checks."""
