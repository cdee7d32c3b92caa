"""A small attitude-filter toolkit: the filters of the texts [A1]-[A4] listed in ``docs/attitude.md``, References.

* :mod:`georef.attitude.kalman` — scalar Kalman filter (with the Arduino heuristic process noise) and a
  generic linear KF with a control input;
* :mod:`georef.attitude.tilt` — accelerometer tilt, complementary filter, angle + gyro-bias Kalman filter;
* :mod:`georef.attitude.mekf` — multiplicative EKF (quaternion + gyro bias) with TRIAD initialisation;
* :mod:`georef.attitude.ukf` — an attitude UKF on the same state (USQUE-style error sigma points);
* :mod:`georef.attitude.compare` — RMS against a reference, constant yaw offset between two series.

Frames follow georef: body FRD, navigation NED, ``C_b_n`` body-to-NED, Hamilton scalar-first quaternions.
"""
