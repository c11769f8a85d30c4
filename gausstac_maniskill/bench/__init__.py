"""Benchmarks: ``python -m gausstac_maniskill.bench <name>`` (see ``__main__``); each prints the
table it measured and writes it under ``out/``. Shared plumbing lives in :mod:`.common`, the scenes
that several benchmarks and tests use in :mod:`.scenes`, the analytic references in
:mod:`gausstac_maniskill.reference`."""
