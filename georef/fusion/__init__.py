"""Navigation solutions: yaw-offset recovery and the fusion methods (``axis`` for now)."""
