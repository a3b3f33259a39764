"""One BLAS thread for a gyrocal process, set before numpy loads (a value the user set is kept).

gyrocal's matrices are small (a few hundred rows): a second BLAS thread gains nothing, and
when the other cores are busy (a fleet run's other jobs) it spins: a diagnosis took 12 s
instead of 4 s beside another job on two cores. With one thread, results do not depend on
the machine's core count either. Imported first by the command line; a program that
imports numpy before gyrocal keeps its own setting.
"""

import os

for name in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(name, "1")
