"""Experiments: specs, sweep runner, tables, figures, reports, benchmarks (the CLIs).

The studies here make many tiny linear-algebra calls (window fits, transfer-function fits,
trilateration batches), which a multi-threaded BLAS runs up to ~40x slower under load than
one thread does. So, before numpy is first imported by any CLI of this package
(``python -m experiments.<name>`` imports this file first), one BLAS/OpenMP thread is the
default; an explicitly set ``OPENBLAS_NUM_THREADS`` / ``OMP_NUM_THREADS`` /
``MKL_NUM_THREADS`` wins. Parallelism comes from worker processes instead (the sweep's
``--jobs``).
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
