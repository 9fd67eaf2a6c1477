"""Old home of the stepping records, kept for one release: import from `prsm_sim` or `prsm_sim.stepping`
(`stepping.records`, `stepping.packed`, `stepping.trajectory`) instead. Importing it warns
(DeprecationWarning); it goes in 0.2.0."""

import warnings

from prsm_sim.stepping.packed import PACKED_STATE_SIZE, PackedConstants, PackedOutputs
from prsm_sim.stepping.records import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs, State
from prsm_sim.stepping.trajectory import Trajectory

__all__ = ["OUTPUT_FIELDS", "PACKED_STATE_SIZE", "InternalBlock", "InternalLayout", "Outputs", "PackedConstants",
           "PackedOutputs", "State", "Trajectory"]

warnings.warn("prsm_sim.outputs is deprecated and goes in 0.2.0: import the records from prsm_sim or "
              "prsm_sim.stepping", DeprecationWarning, stacklevel=2)
