"""Command-line front ends: `prsm-sim`, `prsm-demo` and its controller, example bags, JSON output."""
