"""Studies of many runs on Ray: design sweeps, Monte Carlo spreads and controller-gain tuning.

`study` reads a study YAML into a normalised, hashed description and expands it into run
specs; `execute` runs one spec against `prsm_sim` (no Ray in it); `runner` hands batches of
specs to Ray and writes the Parquet table; `report` and `tune` work on top.
"""
