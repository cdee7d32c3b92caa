"""Public data sets used by tests and benchmarks: the KITTI car log shipped in the gtsam wheel."""
