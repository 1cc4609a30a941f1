"""eskin: a data-versioned experiment pipeline for soft capacitive e-skins."""

import os

__version__ = "0.1.0"

# OpenMP's threads (scikit-learn's gradient boosting and its other OpenMP code; not
# OpenBLAS, whose threads are its own) spin for their next work when idle. Beside any
# other busy process on the machine, a spinning thread holds a core the work needs: a
# gradient-boosted fit of 20,000 rows took 37.6 s with OpenMP's default and 0.89 s with
# passive waiting, beside two busy processes on this machine's 2 cores (issue 55). How
# threads wait moves no result. Set before scikit-learn loads OpenMP; a user's own
# OMP_WAIT_POLICY is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
