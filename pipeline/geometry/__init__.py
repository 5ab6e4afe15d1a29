"""Pure-numpy multi-view geometry."""

from pipeline.geometry.projection import (
    distort_normalized,
    project,
    undistort_points,
    undistort_rig_points,
    world_to_cam,
)

__all__ = ["distort_normalized", "project", "undistort_points", "undistort_rig_points", "world_to_cam"]
