"""The gate layer: where the judge (``mcverify``'s core), the subject (``estimators``)
and the oracle (Mitsuba, ``reference/``) meet.

==================  ==========================================================
``suites``          built-in suites, canaries, seeds, ``run_suite``
``plan``            a scene's features -> the checks it needs (and what it skips)
``render_check``    any renderer's image against a scene's Mitsuba reference
``executors``       where units run: in-process, local processes (-j), Dask
``reference``       Mitsuba reference renders: build, load, staleness
``mitsuba``         the one module that imports Mitsuba (variants, plugin adapters:
                    ``bsdf``, ``emitter``, ``microfacet``, ``phase``)
``mitsuba_suite``   ``--suite mitsuba``: Mitsuba's own plugins over parameter sweeps
``usersuite``       ``--suite MODULE:ATTR`` and ``[tool.mcverify]`` in pyproject.toml
``passes``          K pass images -> mean, variance, n for ``mcverify compare``
``bench``           ours against Mitsuba, as ratios
``report``          JSON -> PNG -> self-contained HTML
``cli``             ``mcverify`` command line
==================  ==========================================================
"""
