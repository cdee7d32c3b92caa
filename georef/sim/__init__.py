"""Flight simulator: trajectories, sensors (IMU, GNSS, POS unit, camera) and the files a real flight leaves."""
