"""
A benchmark of TRLSD on shared-dynamics task families nobody here wrote: MO-Gymnasium envs, each weight
vector of their reward vector a task (``families.py``), against DQN, DQN with the relabelling buffer,
successor features with GPI (``sf_gpi.py``) and a random policy (``peers.py``), run and reported by
``suite.py`` (``sb3-trlsd benchmark-suite``). Needs the ``benchmarks`` extra (``pip install
"sb3-trlsd[benchmarks]"``).
"""
