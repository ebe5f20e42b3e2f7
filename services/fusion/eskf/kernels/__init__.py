"""The filter's compiled kernels, all but the measurement models (`models/`): rotation maths
(`so3`), small products written out (`linalg`), propagation (`propagate`), the Kalman update,
injection and the state's checks (`update`), the rest detector (`rest`), what one IMU sample
does in one call (`steps`), the pose maps' query (`pose_map`) and a published sample's numbers
(`sample`).

Compiled with numba because pure numpy could not reach the offline speed target (a 120 s block
in 2.4 s on one core, with every late vision frame re-propagated): each step is a handful of
16x16 products that numpy dispatches one call at a time. `NUMBA_DISABLE_JIT=1` runs the same
functions as plain Python (slow, same results). Every kernel is compiled through
`jit_cache.njit`, which keeps numba's cache in step with the files kernels compile in from each
other."""
