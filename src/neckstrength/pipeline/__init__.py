"""Pipeline glue: one module per rules file, one function per rule
=================================================================

The only code that knows about file paths and Snakemake. Each function is named like its rule and its
script (``workflow/rules/chapter5.smk`` rule ``chapter5_estimate`` -> ``workflow/scripts/chapter5_estimate.py``
-> :func:`neckstrength.pipeline.chapter5.chapter5_estimate`), reads its inputs, builds typed settings from
the rule's ``params`` with :mod:`neckstrength.config`, calls the science and writes its outputs atomically.

- :mod:`.model`, :mod:`.appendix_a`, :mod:`.chapter3`, :mod:`.chapter4`, :mod:`.chapter5`, :mod:`.chapter6`,
  :mod:`.gap`, :mod:`.report`; :mod:`.common` holds what several share.
"""
