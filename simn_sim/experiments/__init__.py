"""Experiments: episode runner, statistics (``stats``) and the regression gate (``compare``)."""
