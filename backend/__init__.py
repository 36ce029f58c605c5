"""Back-end: the GTSAM iSAM2 factor graph over keyframes and landmarks.

The factor graph knows no images: the front-end sends one ``KeyframeObservations``
(:mod:`osslam.backend.types`) per keyframe to ``IsamBackend.add_keyframe``
(:mod:`osslam.backend.isam`) and applies the returned ``BackendUpdate``. This package
file imports nothing, so the front-end can use the record types without loading GTSAM.
"""
