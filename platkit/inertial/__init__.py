"""Inertial tracking: IMU streams, sensor calibration, filtering and orientation estimation.

- :mod:`platkit.io.imu`: ``imu.csv`` reading with checks (units too) and stated repairs.
- :mod:`platkit.inertial.calibration`: biases, scale factors, the IMU-to-platform misalignment.
- :mod:`platkit.inertial.filters`: low-pass filters, the cut-off from the spectrum's noise floor.
- :mod:`platkit.inertial.paper`: Burlakov et al. (2018): Poisson integration with the
  accelerometer corrections of case A (at rest) and case B (rotation about a fixed axis).
- :mod:`platkit.inertial.estimator`: VQF (the ``vqf`` package) behind platkit's checks, causal
  and offline.
- :mod:`platkit.inertial.command_aided`: fusion of the gyro with the orientation the calibrated
  platform model predicts from the logged commands.
- :mod:`platkit.inertial.simulate`: IMU samples from a known motion, with IMU effects
  (:class:`platkit.effects.ImuEffect` plugins) played through their sensor model.
- :mod:`platkit.inertial.metrics`: orientation errors against a truth (the definitions of Laidig
  et al. 2021). Reading and scoring the BROAD data set: tests/real_data/broad.py.

Quaternions are (w, x, y, z); ``q_earth_from_sensor`` maps sensor coordinates to the earth frame
(z up). An accelerometer at rest reads +|g| along the earth's up axis.
"""
