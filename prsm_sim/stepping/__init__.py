"""Stepping: what every model shares, and the one place each of these is written.

- `stepping.records`: `State` (common coordinates, the ledger and the model's own `part`),
  `Outputs`, `OUTPUT_FIELDS` and the internal-load layout (`InternalLayout`, `InternalBlock`);
- `stepping.ledger`: the energy ledger and its guard (`ledger_step`, `energy_fault`) and `efficiency`,
  in scalar and column form;
- `stepping.packed`: the packed per-step record (`PackedOutputs`) and the ledger's per-step form
  that makes it (`make_finisher`);
- `stepping.trajectory`: `Trajectory`, the columns of a run, and their assembly;
- `stepping.model`: the model contract (`Model`; its docstring says how to write a model) and the
  input checks.

This layer imports nothing above it (no model, no simulator): the models build on it, the model
registry (`models.registry`) and `Simulator` sit above the models.
"""

from prsm_sim.stepping.ledger import ENERGY_GUARD_REL, efficiency, energy_fault, energy_guard_summary
from prsm_sim.stepping.model import Model, check_step_inputs, input_columns
from prsm_sim.stepping.packed import PackedOutputs
from prsm_sim.stepping.records import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs, State
from prsm_sim.stepping.trajectory import Trajectory

__all__ = ["ENERGY_GUARD_REL", "OUTPUT_FIELDS", "InternalBlock", "InternalLayout", "Model", "Outputs",
           "PackedOutputs", "State", "Trajectory", "check_step_inputs", "efficiency", "energy_fault",
           "energy_guard_summary", "input_columns"]
