"""Speed-accuracy study: reference solvers (linear and neo-Hookean FEM, mass-spring), scenes,
metrics, ChainMail calibration and the report behind `chainsim study` (thesis 2.3, 5.2, 6.2).

Everything here is offline tooling: nothing in the interactive hot path imports it.
"""
