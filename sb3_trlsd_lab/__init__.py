"""
The lab of sb3-trlsd: what is run with the library rather than part of it. The reproduction of the paper's
figures (``paper``), the studies beyond it (``studies``), the benchmarks against other methods
(``benchmarks``), the engine that runs them in batches, on processes or a Ray cluster, with a cache of
finished runs (``execution``), the statistics they are reported with (``stats``), and the ``sb3-trlsd``
command line (``cli``). Needs the ``experiments`` extra (``pip install "sb3-trlsd[experiments]"``).

The library, ``sb3_trlsd``, imports nothing of it.
"""
