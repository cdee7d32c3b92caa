"""Navigation solutions: yaw-offset recovery and the fusion methods: the per-axis filter (``axis``), the strapdown
INS with its error-state EKF and RTS smoother (``ekf``, ``rts``) and the GTSAM factor graph (``graph``)."""
