"""DVC stage: acquire one scene into data/raw/<scene>/ (resumes; reuses what is recorded)."""

import sys

from eskin.errors import RECEIVED_KEPT, run_friendly
from eskin.steps.acquire import run as main

if __name__ == "__main__":
    sys.exit(run_friendly(lambda: print(main(sys.argv[1])), interrupted=RECEIVED_KEPT))
