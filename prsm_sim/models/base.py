"""Old home of the model contract and the energy ledger, kept for one release: import from
`prsm_sim.stepping` (`stepping.model`, `stepping.ledger`, `stepping.trajectory`) and the kernel door
`prsm_sim.models.kernels` instead. Importing it warns (DeprecationWarning); it goes in 0.2.0."""

import warnings

from prsm_sim.models.kernels import KERNELS, check_kernel
from prsm_sim.models.kernels import load as load_kernels
from prsm_sim.stepping.ledger import (ENERGY_GUARD_MIN_FLOW_J, ENERGY_GUARD_REL, efficiency, energy_fault,
                                      energy_guard_summary)
from prsm_sim.stepping.model import Model
from prsm_sim.stepping.trajectory import trajectory_from_rows

__all__ = ["ENERGY_GUARD_MIN_FLOW_J", "ENERGY_GUARD_REL", "KERNELS", "Model", "check_kernel", "efficiency",
           "energy_fault", "energy_guard_summary", "load_kernels", "trajectory_from_rows"]

warnings.warn("prsm_sim.models.base is deprecated and goes in 0.2.0: import from prsm_sim.stepping (model, ledger, "
              "trajectory) and prsm_sim.models.kernels", DeprecationWarning, stacklevel=2)
