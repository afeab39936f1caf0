"""The sweep's runner, split by concern (issue 24): a spec in, a results folder out.

- :mod:`~experiments.runner.cell`: one cell, observe -> track -> score (the only part whose
  source is in the cell digest, beside estimator/, sim/, the spec and the technique registry);
- :mod:`~experiments.runner.store`: the results folder (cell files, lock, atomic writes);
- :mod:`~experiments.runner.worker`: what a worker process runs (batches, warm-up);
- :mod:`~experiments.runner.backends`: the executors (in-process, loky, Dask) behind one
  interface, the tasks and the truths;
- :mod:`~experiments.runner.run`: ``run(spec) -> Results``.

:mod:`experiments.sweep` is the command line over it and re-exports the public names.
"""
