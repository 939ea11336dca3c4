import os
import sys

# The host does no large linear algebra: one BLAS thread, so that idle OpenBLAS workers do not
# spin on the cores the OpenCL CPU device works on (set before NumPy loads; the user's own
# setting wins).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from clrender.cli import main  # noqa: E402

sys.exit(main())
