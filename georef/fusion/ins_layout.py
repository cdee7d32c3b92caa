"""Named layouts of the INS/GNSS filter (:mod:`georef.fusion.ins_kernel`): state, noise vector, EM noise
blocks, auxiliary updates, fix status and stop reasons.

Kept apart from the compiled kernel so that the driver, the noise model and the pipeline can name states
without importing numba (0.25 s on every run when the kernels are compiled ahead of time).

One order for the error state and the nominal state:

* error state, estimate minus truth: ``δr`` NED position [m] (POS), ``δv`` NED velocity [m/s] (VEL), attitude
  ``φ`` [rad] with ``Ĉ_b_n = (I - [φ x]) C_b_n`` (ATT), gyro bias [rad/s] (BG), accelerometer bias [m/s^2] (BA),
  the POS unit's own roll/pitch errors [rad] (UNIT_LEVEL, Gauss-Markov), the offset ``d`` of its yaw origin
  [rad] (UNIT_YAW) and that offset's drift rate [rad/s] (UNIT_DRIFT), the time-correlated part of the GNSS
  position error [m, NED] (GNSS_GM, first-order Gauss-Markov: a receiver's fixes wander together over tens of
  seconds, which white noise does not describe); with ``NX_CAL`` states also the GNSS lever arm [m, body] (LEVER)
  and the GNSS time-tag latency [s] (LATENCY), random constants;
* nominal state: the same order with latitude, longitude [rad] and ellipsoidal height [m] for the position and
  the body-to-NED quaternion (scalar first) for the attitude (``X_*`` indices, ``NS`` entries). The lever arm
  and latency are always carried in the nominal state; they are estimated only when the filter has ``NX_CAL``
  states.
"""

from georef.distributions import CHI2_3DOF_99_9

# ---- error state ------------------------------------------------------------------------------------------
POS = 0
VEL = 3
ATT = 6
BG = 9
BA = 12
UNIT_LEVEL = 15
UNIT_YAW = 17
UNIT_DRIFT = 18
GNSS_GM = 19
LEVER = 22
LATENCY = 25
NX_NAV = 22
NX_CAL = 26

# ---- nominal state (same order; quaternion for the attitude) ----------------------------------------------
X_LAT = 0
X_LON = 1
X_HGT = 2
X_VEL = 3
X_QUAT = 6
X_BG = 10
X_BA = 13
X_UNIT_LEVEL = 16
X_UNIT_YAW = 18
X_UNIT_DRIFT = 19
X_GNSS_GM = 20
X_LEVER = 23
X_LATENCY = 26
NS = 27

# ---- noise vector (continuous-time densities, variances and scale factors) --------------------------------
Q_VEL_H = 0        # m^2/s^3, white specific force, north and east
Q_VEL_V = 1        # m^2/s^3, down
Q_ATT_H = 2        # rad^2/s, white angular rate about north and east
Q_ATT_V = 3        # rad^2/s, about down
Q_BG = 4           # rad^2/s^3, gyro-bias Gauss-Markov drive
INV_TAU_G = 5      # 1/s
Q_BA = 6           # m^2/s^5, accelerometer-bias drive
INV_TAU_A = 7      # 1/s
Q_UNIT_LEVEL = 8   # rad^2/s, drive of the unit's roll/pitch errors
INV_TAU_UNIT = 9   # 1/s
Q_UNIT_DRIFT = 10  # rad^2/s^3, random walk of the unit's yaw-origin drift rate
R_UNIT_LEVEL = 11  # rad^2, white noise of the unit's roll and pitch
R_UNIT_YAW = 12    # rad^2, of its yaw
R_SCALE_H = 13     # factor on the GNSS north/east variances
R_SCALE_V = 14     # factor on the GNSS down variance
R_NHC = 15         # m^2/s^2, non-holonomic constraint: variance of the body's lateral and vertical velocity
Q_GNSS_GM_H = 16   # m^2/s, drive of the correlated GNSS error, north and east
Q_GNSS_GM_V = 17   # m^2/s, down
INV_TAU_GNSS = 18  # 1/s, its inverse correlation time
R_ZUPT = 19        # m^2/s^2, variance of the velocity of a vehicle standing still (zero-velocity update)
R_ZARU = 20        # rad^2/s^2, variance of the epoch's mean angular rate of a vehicle standing still
N_NOISE = 21

# ---- noise blocks whose EM statistics the smoother adds up ------------------------------------------------
B_GNSS_H = 0
B_GNSS_V = 1
B_UNIT_R_LEVEL = 2
B_UNIT_R_YAW = 3
B_VEL_H = 4
B_VEL_V = 5
B_ATT_H = 6
B_ATT_V = 7
B_BG = 8
B_BA = 9
B_UNIT_LEVEL = 10
B_UNIT_DRIFT = 11
B_NHC = 12
B_OUTAGE = 13      # all process noise inside GNSS outages, pooled (a scale on top of the other blocks)
B_GNSS_GM_H = 14
B_GNSS_GM_V = 15
N_BLOCKS = 16

# ---- kinds of the auxiliary (non-GNSS) updates ------------------------------------------------------------
AUX_UNIT = 0       # the unit's roll, pitch, yaw (3)
AUX_NHC = 1        # a ground vehicle's zero lateral and vertical body velocity (2)
AUX_ZUPT = 2       # a vehicle standing still: zero NED velocity (3)
AUX_ZARU = 3       # a vehicle standing still: no angular rate but the Earth's (3), which pins the gyro bias
#: chi-square(3) gate of the zero-velocity update (99.9 %): a vehicle read as still that moves is refused
ZUPT_GATE = CHI2_3DOF_99_9
#: how far from the IMU the point is at which a ground vehicle has no lateral or vertical velocity [m]
NHC_LEVER = 2.0
#: chi-square(2) gate of the NHC update (1 - 1e-20)
NHC_GATE = 92.1

# ---- options of a forward pass (ins_kernel.ekf_forward's ``options`` vector) ---------------------------------
OPT_STRIDE = 0       # IMU rows between covariance epochs
OPT_GATE = 1         # chi-square gate of a GNSS fix and of the unit's attitude
OPT_MAX_REJECTS = 2  # GNSS fixes rejected in a row that stop the pass (0: never)
OPT_MAX_GAP = 3      # s, an IMU gap longer than this stops the pass
OPT_OUTAGE_S = 4     # s, a GNSS outage longer than this opens the drift window (DRIFT_WINDOW)
OPT_UNIT_AIDING = 5  # 1.0: fuse the unit's roll, pitch, yaw
OPT_NHC = 6          # 1.0: fuse a ground vehicle's non-holonomic constraint
N_OPTIONS = 7

# ---- covariance propagation ---------------------------------------------------------------------------------
#: the longest step [s] an epoch interval is propagated in; epochs are at most 0.5 s apart at the rates used, so
#: only intervals stretched by sparse fixes are split
STEP_S = 1.0
#: the step [s] inside an IMU gap, where the navigation noise is raised to that of unknown motion
GAP_STEP_S = 0.05

# ---- GNSS fix status and why a forward pass stopped -------------------------------------------------------
FIX_UNUSED = -1
FIX_REJECTED = 0
FIX_USED = 1
STOP_END = 0
STOP_DIVERGED = 1
STOP_GAP = 2
STOP_DRIFT = 3
#: rejected fixes in a row, starting within DRIFT_WINDOW fixes after a GNSS outage or an IMU gap, that stop a
#: pass with STOP_DRIFT
DRIFT_REJECTS = 2
DRIFT_WINDOW = 5
#: the first REACQUIRE_FIXES fixes after a GNSS outage or an IMU gap are gated only at REACQUIRE_GATE
#: (chi-square(3) 1 - 1e-20): they correct the drift of the gap, which is what a normal gate would reject
REACQUIRE_FIXES = 3
REACQUIRE_GATE = 97.0
