"""
TRLSD against other methods: SB3's DQN and a random policy on the task families of ``sb3_trlsd_envs``
(``benchmark``, ``baselines``), and the MO-Gymnasium suite (``mo_suite``).
"""
