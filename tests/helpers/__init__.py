"""Helpers shared by the test directories (importable as ``helpers``: pytest's ``pythonpath``
includes ``tests``): :mod:`helpers.training` the small predictor's training data,
:mod:`helpers.twin` a twin's coach-params file, :mod:`helpers.cli` the command line in-process,
:mod:`helpers.service` the service's telemetry rows, databases and waits,
:mod:`helpers.processes` the service as child processes."""
