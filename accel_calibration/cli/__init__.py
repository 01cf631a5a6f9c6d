"""The accel-calib command line: one function per command, each returning an exit code."""

import os

# One BLAS thread unless the user says otherwise, set before numpy loads OpenBLAS: the commands' products
# are tall and thin (N x 3 by 3 x 3, per-motion sums), memory-bound, where OpenBLAS's threads only spin
# (on 2 shared cores they doubled the gyro fit's CPU time and slowed it in wall time too), and a thread
# count taken from the machine would make a threaded reduction's rounding depend on the CPU.
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")
