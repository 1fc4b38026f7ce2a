"""Studies: the runs behind a page of results, declared in ``conf/study/<name>.yaml``.

A study names the runs it is made of (an experiment with its overrides, seeds and sweep axes, or a developer tool's
command), the tables they make and the page each table is on. ``rmpfusion-study run`` runs them as Hydra multiruns,
``store`` keeps their metrics under ``results/<study>/``, ``table`` regenerates the page's tables from what is stored
and ``check`` compares a fresh run with the stored one (docs/results/README in the repository's ``results/``).
"""
