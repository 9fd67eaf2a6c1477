"""The model levels behind the one stepping contract (`prsm_sim.stepping.model.Model`): ideal, jones2016,
fu2018, elastic; `models.registry` names them (`MODELS`, `build_model`), `models.kernels` is the door to
their compiled steps.

.. include:: ../../docs/model.md
"""
