"""`prsm-bench`: performance figures beside their targets, one module per area."""
