"""`python -m prsm_ros.node`: the same as `prsm-node` (`prsm_ros.node.process`)."""

import sys

from prsm_ros.node.process import main

sys.exit(main())
