"""`prsm-fit`: bench recordings in (MCAP bags, CSV/Parquet tables), an identified parameter file out.

`readers` turns a file into a `prsm_sim.identify.Recording`; `cli` runs the fit (`prsm_sim.identify`)
with its starts on Ray or in this process, `plots` draws measured against fitted, `excite` writes an
identification signal that `prsm-ctl play` sends to a node.
"""
