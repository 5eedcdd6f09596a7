"""Analysis scripts: the studies bayeshyst's users run, each a small driver over the API.

Run any of them from the repository root as a module, e.g.
``python -m analyses.uncertainty_report --quick``; every script has ``main(argv)``,
``--quick`` (a seconds-long smoke run, the one the test suite exercises), ``--out DIR``
and ``--seed N``. See each module's docstring for what it answers.
"""
