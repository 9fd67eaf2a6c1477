"""prsm_ros: the I/O side of prsm — ROS 2 node, MCAP recording, bag tools, Rerun (imports stay lazy)."""

import os

# Before numpy loads (every prsm command imports this package first). The matrices here are a few rows, so
# BLAS threads only cost, and with every core busy OpenBLAS's spin-wait starves the very threads it waits
# for (eleven nodes started at once spent minutes in one 10 x 10 expm). One thread also fixes the bits:
# scipy's expm of the 17 x 17 Van Loan matrix behind the friction work form differs in the last bit with the
# thread count, so a session in one process and a node in another agree bit for bit only on the same count.
# A value the user set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

