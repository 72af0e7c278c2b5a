"""Experiments over many episodes: scenes at an occlusion density, paired trials,
sweeps on local or Dask workers, the results database and its report, the Figure 7
study, and the soak of unfamiliar scenes with its auditor."""
