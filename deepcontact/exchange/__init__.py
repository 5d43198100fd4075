"""Exchange with other tools: a step's problem in FCLIB's HDF5 format (`dc export`) and Siconos,
the independent peer solver, run on those files in Debian's own Python."""
