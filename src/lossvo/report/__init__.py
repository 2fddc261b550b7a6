"""The sweep report: ``python -m lossvo.report SWEEP_DIR`` turns a Hydra sweep's job folders into the
study's tables, figures and claims, reading only what the jobs wrote.

A Hydra multirun (``python -m lossvo.train -m loss=euler,quat,chordal [seed=0,1,2]``) leaves one job folder
per run, ``SWEEP_DIR/<num>_<overrides>/``, with ``.hydra/{config,overrides}.yaml``, ``status.json``,
``metrics.csv``, ``results.json`` and ``trajectories/NN.txt``. The report writes into ``--out`` (default
``SWEEP_DIR/report/``) ``report.md``, ``tables/`` (CSV and LaTeX) and ``figures/`` (PNG), and caches the
baselines under ``cache/``. It never builds a datamodule: the evaluated dataset, its ground-truth pose
files, the training split and the unseen-motion sequences come from each job's results.json.

Configurations are named by the overrides that differ between jobs (``loss=euler`` vs ``loss=quat``, or
``loss.k=50`` vs ``loss.k=100``); ``seed`` is the replicate axis: with several seeds a cell is the mean ±
sample standard deviation (ddof = 1) over seeds.

Modules, by concern:

- :mod:`~lossvo.report.jobs`: the sweep folder and its job folders (Job, status, metrics.csv curves,
  results.json with its data record, trajectories and ground truth);
- :mod:`~lossvo.report.configurations`: jobs grouped into configurations, rotation weights, selection;
- :mod:`~lossvo.report.tables`: the per-sequence tables and their markdown, CSV and LaTeX;
- :mod:`~lossvo.report.statistics`: Wilcoxon tests, paired tests, the verdict rule, convergence epochs;
- :mod:`~lossvo.report.comparison`, :mod:`~lossvo.report.convergence`, :mod:`~lossvo.report.claims`:
  the pairwise comparison, the convergence epochs and the study's claims;
- :mod:`~lossvo.report.baselines`: zero motion, training mean motion, ORB + E, own mean motion;
- :mod:`~lossvo.report.against_baselines`: the baselines' columns and section, each job against them;
- :mod:`~lossvo.report.figures`: curves, trajectories, APE bars;
- :mod:`~lossvo.report.document`: report.md and the files (:func:`~lossvo.report.document.make_report`);
- :mod:`~lossvo.report.cli`: the command line.
"""
