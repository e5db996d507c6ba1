"""Controllers on the flattened model (next issues: linearisation to python-control,
PID, LQR, linear and nonlinear MPC on CasADi). Nothing here yet."""
