"""The measurement models, one per file: each gives its update's Jacobian H (m, 16) and
innovation y (measured minus predicted) for `kernels.update.update`, H in the error state of
`layout`. Those used at the IMU's or the ToF's rate are compiled with numba (`kernels`);
vision's, at the frame rate, are numpy."""
