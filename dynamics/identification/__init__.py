"""Parameter identification on the flattened model's CasADi Functions (docs/fitting.md).

- :mod:`.experiments`: estimated parameters, noise, time series, static points, targets;
- :mod:`.shooting`: multiple shooting with Radau IIA collocation (exact derivatives);
- :mod:`.problem`: the least-squares problem (:class:`~.problem.Problem`), its residuals,
  constraints and sparse Jacobians; :mod:`.gauss_newton` solves it;
- :mod:`.estimate`: one fit from one start, noise levels by maximum likelihood;
- :mod:`.uncertainty`: sensitivities, Fisher covariance, profiles, verdicts;
- :mod:`.design`: ranking candidate experiments by D-optimality.
"""
