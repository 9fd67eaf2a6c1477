"""The actuator as an FMI co-simulation FMU: `prsm-fmu build` (FMI 2.0 with pythonfmu, FMI 3.0 with pythonfmu3).

`config` is what an FMU is built from (written into its resources), `core.SlaveCore` the slave
logic both FMI versions share, `slave_fmi2` / `slave_fmi3` the modules the FMUs load, `build` the
builder, `cli` the command and `driver` an importer's side through fmpy (tests, prsm-bench). Only
`slave_fmi2`, `slave_fmi3` and `build` import pythonfmu / pythonfmu3, only `driver` fmpy
(`pip install 'prsm[fmu]'`). docs/fmu.md is the user's page.
"""
