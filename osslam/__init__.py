"""OS-SLAM: dynamic-scene RGB-D SLAM with a GTSAM iSAM2 back-end."""

__version__ = "0.1.0"
