"""Front-end: ORB features, local-map tracking, keyframe selection."""
